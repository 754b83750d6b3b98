"""What sensor poses off by a hand's kinematic error leave to any estimator: a lower bound on the positional error.

    python scripts/kinematic_bound.py --artifacts artifacts --scenes kinematic [--sequences] [override ...]

For each scene of a set whose sensor poses were made wrong on purpose (``pose_error_*`` in the scenes file, as
``kinematic``), the oracle of ``tactile6d.evaluation.kinematic_bound`` is told each sensor's pose relative to the
object exactly (more than any image can tell) and still has to place the object through the reported poses.
Printed per set, in cm, mean (median) over scenes: the oracle's expected positional error under the declared
sigmas (``sensors.pose_sigma_mm`` / ``_deg``, the set's own by default), its error for the errors the set drew,
and the estimator's best pose (``artifacts/runs/<set>/ours/ranked.h5``, when the pipeline made it).
``--sequences``: also the tracking sequences' frames (``artifacts/sequences/tracking.h5``, true and reported
sensor poses). A diagnostic: it writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.evaluation.kinematic_bound import scene_bound, true_sensor_poses  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def summary(values_m: list[float]) -> str:
    return f"{100 * np.mean(values_m):.2f} ({100 * np.median(values_m):.2f})"


def set_bounds(scenes, sigma_m: float, sigma_rad: float) -> tuple[list[float], list[float]]:
    """Per scene of a scene artifact -> (expected, realised) oracle positional errors, m."""
    expected, realised = [], []
    for s in range(len(scenes["names"])):
        T_true = true_sensor_poses(scenes, s)
        if T_true is None:
            raise SystemExit("this scene set stored no sensor-pose errors (pose_error_*): nothing to bound")
        e, r = scene_bound(np.asarray(scenes["T_world_object"][s]), T_true, np.asarray(scenes["T_world_sensors"][s]),
                           sigma_m, sigma_rad)
        expected.append(e)
        realised.append(r)
    return expected, realised


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="*", default=["kinematic"], help="scene sets (artifacts/scenes/<set>.h5)")
    parser.add_argument("--sequences", action="store_true", help="also the tracking sequences' frames")
    parser.add_argument("--sigma-mm", type=float, default=None, help="declared error per axis (default: the set's)")
    parser.add_argument("--sigma-deg", type=float, default=None)
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    print("positional error, cm, mean (median) over scenes")
    for scene_set in args.scenes:
        kin = cfg.scenes[scene_set].get("kinematics")
        sigma_mm = args.sigma_mm if args.sigma_mm is not None else float(kin.sigma_mm if kin else cfg.sensors.pose_sigma_mm)
        sigma_deg = args.sigma_deg if args.sigma_deg is not None else float(kin.sigma_deg if kin else cfg.sensors.pose_sigma_deg)
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        expected, realised = set_bounds(scenes, 1e-3 * sigma_mm, np.radians(sigma_deg))
        line = (f"{scene_set} ({len(expected)} scenes, {sigma_mm:g} mm / {sigma_deg:g} deg): oracle expected "
                f"{summary(expected)}, oracle for the errors drawn {summary(realised)}")
        ranked_file = layout.run_dir(args.artifacts, scene_set, "ours") / "ranked.h5"
        if ranked_file.exists():
            ranked = read_artifact(ranked_file, "ranked")
            best = [float(np.linalg.norm(ranked["poses"][s][0][:3, 3] - scenes["T_world_object"][s][:3, 3]))
                    for s in range(len(expected))]
            line += f", the estimator's best pose {summary(best)}"
        print(line, flush=True)
    if args.sequences:
        seq = read_artifact(layout.sequences_file(args.artifacts, "tracking"), "sequences")
        sigma_m, sigma_rad = 1e-3 * cfg.sequences.pose_sigma_mm, np.radians(cfg.sequences.pose_sigma_deg)
        expected, realised = [], []
        for q in range(len(seq["objects"])):
            T_wo, T_true, T_rep = (np.asarray(seq[k][q]) for k in ("T_world_object", "T_world_sensors_true",
                                                                    "T_world_sensors"))
            for f in range(len(T_wo)):
                e, r = scene_bound(T_wo[f], T_true[f], T_rep[f], sigma_m, sigma_rad)
                expected.append(e)
                realised.append(r)
        print(f"tracking sequences ({len(expected)} frames): oracle expected {summary(expected)}, "
              f"oracle for the errors drawn {summary(realised)}")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
