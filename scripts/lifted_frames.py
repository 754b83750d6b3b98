"""Single-shot estimates of the tracking sequences' frames, those where a sensor shows no contact apart.

    python scripts/lifted_frames.py --artifacts artifacts [--every 3] [--true-sensors] [override ...]

Every ``--every``-th frame of each sequence of ``artifacts/sequences/tracking.h5`` (stage make_sequences: in
half of them one sensor lifts 3 mm off for 0.3 s) is estimated from scratch with the default estimator, as
stage evaluate_tracking's single-shot frames are, through the sensor poses as the hand reports them (or the
true ones). The frames are split by what the images show: every sensor's image shows contact, or some do
not (a lifted sensor, read as ``Contacts.from_patch``). Per group it prints how many frames, how many the
estimator could not estimate (``NoMatch``), the positional error of the best pose (median and mean, cm),
how many are 1 cm or more off, and the mean confidence against the share of best poses within 1 cm ADI (the
event the confidence gives the probability of; ``metrics.adi`` on the object's scoring points). Written against
``Contacts.from_patch``, which every version of the estimator has, so that it runs on a checkout from
before the estimator left untouched sensors out (docs/real_sensors.md says how). A diagnostic: it writes
nothing.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core import metrics  # noqa: E402
from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.errors import NoMatch  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.evaluation import scoring  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

GROUPS = ("all touching", "some not touching")


def group_line(name: str, errors_cm: list[float], failed: int, confidence: list[float], adi_cm: list[float]) -> str:
    """One group's figures: frames, failures, positional error median (mean) cm over the estimated ones, how
    many are 1 cm or more off, mean confidence (NaN entries: no confidence model) against the share of ADIs
    (``adi_cm``, one per estimated frame) under 1 cm."""
    e = np.asarray(errors_cm, dtype=np.float64)
    line = f"{name}: {len(e) + failed} frames, {failed} not estimated (NoMatch)"
    if len(e) == 0:
        return line
    line += (f"; positional error median {np.median(e):.2f} cm, mean {e.mean():.2f}; {int((e >= 1).sum())} of {len(e)} "
             f"1 cm or more off")
    c = np.asarray(confidence, dtype=np.float64)
    if np.isfinite(c).any():
        line += f"; mean confidence {np.nanmean(c):.2f} against {(np.asarray(adi_cm) < 1).mean():.2f} within 1 cm ADI"
    return line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--every", type=int, default=3, help="estimate every this many frames (evaluate_tracking's 3)")
    parser.add_argument("--true-sensors", action="store_true", help="through the true sensor poses")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parser.parse_args(argv)
    cfg = compose_config(args.overrides)
    seq = read_artifact(layout.sequences_file(args.artifacts, "tracking"), "sequences")
    poses = "T_world_sensors_true" if args.true_sensors else "T_world_sensors"
    errors = {g: [] for g in GROUPS}
    failed = {g: 0 for g in GROUPS}
    confidence = {g: [] for g in GROUPS}
    adi = {g: [] for g in GROUPS}
    for q in range(len(seq["objects"])):
        obj = str(seq["objects"][q])
        estimator = Estimator.from_artifacts(obj, args.artifacts, cfg)
        reference = scoring.load_object_reference(args.artifacts, obj)
        for f in range(0, len(seq["images"][q]), args.every):
            T, images = np.asarray(seq[poses][q][f]), np.asarray(seq["images"][q][f])
            # which images show contact, as the estimator reads them (light aligned first)
            touching = estimator.contacts(T, estimator.align_light(images)[0]).from_patch
            group = GROUPS[0] if touching.all() else GROUPS[1]
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    estimate = estimator.estimate(T, images)
            except NoMatch as exc:
                failed[group] += 1
                print(f"{seq['names'][q]} frame {f}: {group}, not estimated: {exc}", flush=True)
                continue
            truth = np.asarray(seq["T_world_object"][q][f])
            error = 100 * float(np.linalg.norm(estimate.best[:3, 3] - truth[:3, 3]))
            errors[group].append(error)
            adi[group].append(100 * float(metrics.adi(reference.points, estimate.best, truth, reference.tree)))
            confidence[group].append(np.nan if estimate.confidence is None else estimate.confidence)
            if group == GROUPS[1]:
                print(f"{seq['names'][q]} frame {f}: touching {touching.astype(int).tolist()}, {error:.2f} cm off, "
                      f"ADI {adi[group][-1]:.2f} cm, confidence {confidence[group][-1]:.2f}", flush=True)
    for g in GROUPS:
        print(group_line(g, errors[g], failed[g], confidence[g], adi[g]))
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
