"""Is the confidence calibrated when a sensor does not touch? The confidence scenes with one sensor lifted off.

    python scripts/two_contact_confidence.py --artifacts artifacts [--lift-mm 4] [--seed 0] [override ...]

The confidence model (stage calibrate_confidence) is fitted on scenes where all three sensors touch. Each of
those scenes (``artifacts/scenes/confidence.h5``, stage make_confidence_scenes) is estimated here again with
one sensor lifted off: sensor ``s mod 3`` of scene s moved ``--lift-mm`` away from the object along the
surface's outward normal at its contact (the reported and the true pose alike, so its kinematic error stays),
and its image replaced by what the unit then sees: the no-contact image the scenes were rendered over
(``render.background``) under that sensor's drifted light (``sim.perturb.drift_image_light``, the scene's own
gain and gamma) plus the scene's camera noise. The estimator leaves the lifted sensor out of its selection and
fit (docs/real_sensors.md, "A finger that does not touch"), so each estimate rests on two contacts.

Prints the share of best poses within 1 cm ADI, the mean confidence, the confidence's AUROC and Brier score
for "ADI < 1 cm" and its reliability bins, beside the same figures of the fit set as the stage recorded them
(``artifacts/confidence/fit.json``, three contacts). A diagnostic: it writes nothing.
"""

from __future__ import annotations

import argparse
import json
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
from tactile6d.estimation import confidence  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.evaluation import scoring  # noqa: E402
from tactile6d.perception.encode import load_background  # noqa: E402
from tactile6d.sim.perturb import add_camera_noise, drift_image_light  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def lift_sensor(T_world_sensors: np.ndarray, images: np.ndarray, sensor: int, normal: np.ndarray, distance: float,
                no_contact: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A scene's sensor poses (L, 4, 4) and images (L, H, W, 3) with ``sensor`` moved ``distance`` (m) along the
    object's outward ``normal`` (3,) at its contact and its image replaced by ``no_contact`` (H, W, 3) -> copies."""
    T, out = np.array(T_world_sensors, dtype=np.float64), np.array(images)
    T[sensor, :3, 3] += distance * np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    out[sensor] = no_contact
    return T, out


def summary_line(name: str, probability: np.ndarray, success: np.ndarray) -> str:
    """A set's figures: estimates, share within 1 cm ADI, mean confidence, AUROC, Brier score."""
    p, ok = np.asarray(probability, dtype=np.float64), np.asarray(success, dtype=bool)
    return (f"{name}: {len(p)} estimates, {ok.mean():.3f} within 1 cm ADI, mean confidence {p.mean():.3f}, "
            f"AUROC {confidence.auroc(p, ok):.3f}, Brier {confidence.brier(p, ok):.3f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--lift-mm", type=float, default=4.0, help="how far the lifted sensor moves off (mm)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the lifted images' camera noise")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parser.parse_args(argv)
    cfg = compose_config(args.overrides)
    scenes = read_artifact(layout.scenes_file(args.artifacts, "confidence"), "scenes")
    noise_std = float(cfg.confidence.scenes.light.noise_std)
    background = load_background(cfg)
    rng = np.random.default_rng(args.seed)
    estimators, references = {}, {}
    probability, success, failed = [], [], 0
    for s in range(len(scenes["names"])):
        obj, sensor = str(scenes["objects"][s]), s % 3
        if obj not in estimators:
            estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
            references[obj] = scoring.load_object_reference(args.artifacts, obj)
        no_contact = add_camera_noise(drift_image_light(background, scenes["light_gain"][s][sensor],
                                                        scenes["light_gamma"][s][sensor]), noise_std, rng)
        T, images = lift_sensor(scenes["T_world_sensors"][s], scenes["images"][s], sensor,
                                scenes["contact_normals"][s][sensor], 1e-3 * args.lift_mm, no_contact)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the untouched sensor's, and the drifted light's, expected here
                estimate = estimators[obj].estimate(T, images, scenes["backgrounds"][s])
        except NoMatch:
            failed += 1
            continue
        truth = np.asarray(scenes["T_world_object"][s])
        adi = float(metrics.adi(references[obj].points, estimate.best, truth, references[obj].tree))
        probability.append(estimate.confidence)
        success.append(adi < confidence.SUCCESS_ADI)
        print(f"{scenes['names'][s]}: sensor {sensor} lifted, {int(np.sum(estimate.contacts.touching))} touching, "
              f"ADI {100 * adi:.2f} cm, confidence {estimate.confidence:.2f}", flush=True)
    if None in probability:
        raise SystemExit("no confidence model in the artifacts: `dvc repro calibrate_confidence` makes it")
    p, ok = np.array(probability), np.array(success)
    fit = json.loads((Path(args.artifacts) / "confidence" / "fit.json").read_text())
    print(summary_line("three contacts (the fit set, fit.json)", np.array([v["probability"] for v in fit.values()]),
                       np.array([v["adi_m"] < confidence.SUCCESS_ADI for v in fit.values()])))
    print(summary_line(f"two contacts (one sensor lifted {args.lift_mm:g} mm; {failed} not estimated)", p, ok))
    for b in confidence.reliability(p, ok):
        print(f"  confidence {b['low']:.1f}-{b['high']:.1f}: {b['count']} estimates, predicted {b['predicted']:.2f}, "
              f"observed {b['observed']:.2f}")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
