"""Could a tracked frame's confidence come from the tracker's own state? Per-frame features, held-out AUROC.

    python scripts/track_frame_confidence.py --artifacts A [--artifacts B ...] [override ...]

Each ``--artifacts`` folder's sequences (``sequences/tracking.h5``) are tracked as stage evaluate_tracking
tracks them (default settings, one thread, the sensor poses as the hand reports them). After every frame the
tracker's hypotheses give the features below, and the frame is *right* when its reported pose is within
1 cm ADI of the truth (``confidence.SUCCESS_ADI``), as the single-shot confidence predicts:

- ``confidence``: what a frame reports today, the last re-detection's calibrated confidence (as a logit);
- ``rival_gap``, ``spread_cm``: the single-shot confidence's two features (``tactile6d.estimation.confidence``)
  on the hypotheses followed, leader first, their evidence as scores;
- ``evidence_mm``: the leader's evidence (its running mean score), ``residual_mm``, ``agreement``,
  ``penetration_mm``: its last fit terms; ``hypotheses``: how many are followed; ``frames_since``: frames
  since the last re-detection.

Printed: each feature's AUROC alone on each set (higher = right frames score higher, the sign chosen per
feature as a confidence would use it), then a logistic regression (``confidence.fit_logistic``) on
``confidence`` plus each group of the others, fitted on each set and scored on every set. A feature adds
something only if the fit beats ``confidence`` alone on the sets it was not fitted on. A diagnostic: it
writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation import confidence  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.optimize import use_cpu_devices_for  # noqa: E402
from tactile6d.estimation.tracker import Tracker, TrackSettings  # noqa: E402
from tactile6d.evaluation import scoring  # noqa: E402
from tactile6d.evaluation.tracking_accuracy import pose_errors  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

FEATURES = ("confidence", "rival_gap", "spread_cm", "evidence_mm", "residual_mm", "agreement", "penetration_mm",
            "hypotheses", "frames_since")
# +1: a larger value should mean a right frame; -1: a smaller one.
SIGNS = {"confidence": 1, "rival_gap": 1, "spread_cm": -1, "evidence_mm": -1, "residual_mm": -1, "agreement": -1,
         "penetration_mm": -1, "hypotheses": -1, "frames_since": -1}
GROUPS = (("spread_cm",), ("rival_gap", "spread_cm"), ("spread_cm", "penetration_mm", "evidence_mm"))


def tracker_features(tracker: Tracker, frame_confidence: float | None) -> np.ndarray:
    """The features (``FEATURES`` order) of the tracker's state after a frame -> (9,); NaN where there is no
    hypothesis (a held frame before any pose) or the leader has no fit terms yet (a re-detected one)."""
    row = np.full(len(FEATURES), np.nan)
    if frame_confidence is not None:
        p = float(np.clip(frame_confidence, 1e-4, 1 - 1e-4))
        row[0] = np.log(p / (1 - p))
    hypotheses = sorted(tracker._hypotheses, key=lambda h: h.evidence)  # leader first
    row[7], row[8] = len(hypotheses), tracker._frames_since_redetect
    if not hypotheses:
        return row
    poses = np.stack([h.poses[-1] for h in hypotheses])
    evidence = np.array([h.evidence for h in hypotheses])
    row[1:3] = confidence.features(evidence, confidence.distances_from_best(tracker.estimator.spread_points, poses))
    residual, agreement, penetration = hypotheses[0].terms
    row[3:7] = 1e3 * evidence[0], 1e3 * residual, agreement, 1e3 * penetration
    return row


def track_set(artifacts: str, cfg) -> tuple[np.ndarray, np.ndarray]:
    """Every frame of a folder's sequences tracked -> features (F, 9), right (F,) bool."""
    art = read_artifact(layout.sequences_file(artifacts, "tracking"), "sequences")
    settings = replace(TrackSettings.from_cfg(cfg.track), threads=1)
    rows, right = [], []
    for q, obj in enumerate(str(o) for o in art["objects"]):
        estimator = Estimator.from_artifacts(obj, artifacts, cfg)
        T, images = np.asarray(art["T_world_sensors"][q]), np.asarray(art["images"][q])
        poses = []
        with Tracker(estimator, settings) as tracker:
            for f in range(len(T)):
                answer = tracker.update(T[f], images[f])
                poses.append(answer.pose)
                rows.append(tracker_features(tracker, answer.confidence))
        ref = scoring.load_object_reference(artifacts, obj)
        adi = pose_errors(ref.points, np.stack(poses), np.asarray(art["T_world_object"][q]), ref.tree)["adi"]
        right.append(adi < confidence.SUCCESS_ADI)
        print(f"{artifacts}: {art['names'][q]}: {np.mean(~right[-1]):.0%} of frames wrong", flush=True)
    return np.stack(rows), np.concatenate(right)


def standardised(x: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Features centred and scaled by a fit set's statistics, NaN (no value) as that set's mean."""
    return np.nan_to_num((x - mean) / std, nan=0.0)


def held_out_aurocs(sets: dict[str, tuple[np.ndarray, np.ndarray]], columns: list[int]) -> dict[str, dict[str, float]]:
    """A logistic regression on ``columns`` fitted on each set -> {fit set: {scored set: AUROC}}."""
    out = {}
    for fit_name, (x_fit, y_fit) in sets.items():
        x = x_fit[:, columns]
        mean, std = np.nanmean(x, axis=0), np.nanstd(x, axis=0) + 1e-12
        w, b = confidence.fit_logistic(standardised(x, mean, std), y_fit.astype(np.float64))
        out[fit_name] = {name: confidence.auroc(confidence.sigmoid(standardised(xs[:, columns], mean, std) @ w + b), ys)
                         for name, (xs, ys) in sets.items()}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", action="append", required=True, help="an artifacts folder with sequences/")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parser.parse_args(argv)
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    sets = {a: track_set(a, cfg) for a in args.artifacts}
    print("\nAUROC of each feature alone (frames with a value; wrong = ADI >= 1 cm):")
    for name, (x, right) in sets.items():
        cells = []
        for j, feature in enumerate(FEATURES):
            ok = np.isfinite(x[:, j])
            value = confidence.auroc(SIGNS[feature] * x[ok, j], right[ok]) if 0 < right[ok].sum() < ok.sum() else np.nan
            cells.append(f"{feature} {value:.3f}")
        print(f"  {name} ({len(right)} frames, {int((~right).sum())} wrong): " + ", ".join(cells))
    print("\nlogistic regression, fitted on one set (*) and scored on each:")
    for group in ((),) + GROUPS:
        columns = [0] + [FEATURES.index(f) for f in group]
        for fit_name, scores in held_out_aurocs(sets, columns).items():
            cells = ", ".join(f"{n}{'*' if n == fit_name else ''} {v:.3f}" for n, v in scores.items())
            print(f"  confidence{''.join(' + ' + f for f in group)}: {cells}")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
