"""How close could any estimate get? Each scene's estimate against its floor: the true pose refined and scored.

    python scripts/pose_floor.py --artifacts artifacts --scenes kinematic validation [--true-sensors] [override ...]

For every scene of the sets, the default estimator (as stage rank runs it: images and each sensor's no-contact
image) gives its best pose; then the true pose alone goes through the ranking's re-scoring
(``Estimator.rank`` with the scene's contacts: refinement through the sensor poses given, each sensor's
correction included, then the ranking's score). That refined true pose is the *floor*: where the estimator's
own fit puts the truth, so its positional error is what the data leave (sensor-pose errors, the contacts'
reading), whatever the search. Per set it prints the positional error #1 (mean, median), the floor's, and for
each scene whose best pose is over ``--wrong-cm`` off whether the truth scored worse than the winner (the
score prefers the wrong pose) or better (the search missed it).

``--true-sensors``: on a set whose sensor poses were made wrong on purpose (``pose_error_*`` in the scenes
file, as ``kinematic``), also estimate through the true sensor poses, to see what the error costs.
A diagnostic: it changes nothing and writes nothing.
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
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.evaluation.kinematic_bound import true_sensor_poses  # noqa: E402
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402


def position_cm(T: np.ndarray, truth: np.ndarray) -> float:
    return float(100 * np.linalg.norm(T[:3, 3] - truth[:3, 3]))


def summary(name: str, errors: list[float]) -> str:
    return f"{name} {np.mean(errors):.2f} cm (median {np.median(errors):.2f})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", required=True, help="scene sets (artifacts/scenes/<set>.h5)")
    parser.add_argument("--wrong-cm", type=float, default=1.0, help="a best pose this far from the truth is wrong")
    parser.add_argument("--true-sensors", action="store_true", help="also estimate through the true sensor poses")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parser.parse_args(argv)
    cfg = compose_config(args.overrides)
    if not cfg.rank.refine:
        raise SystemExit("the floor is the true pose refined as the ranking refines: needs rank.refine")
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        estimators: dict[str, Estimator] = {}
        best, floor, through_true, scored_worse, missed = [], [], [], 0, 0
        for s in range(len(scenes["names"])):
            obj = str(scenes["objects"][s])
            if obj not in estimators:
                estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
            est, truth = estimators[obj], np.asarray(scenes["T_world_object"][s])
            T, images, backgrounds = scenes["T_world_sensors"][s], scenes["images"][s], scene_backgrounds(scenes, s)
            estimate = est.estimate(T, images, backgrounds)
            refined = est.rank(T, truth[None], np.zeros(1), estimate.contacts)
            best.append(position_cm(estimate.best, truth))
            floor.append(position_cm(refined.poses[0], truth))
            line = f"{scene_set} {s:3d} {obj:22s} best {best[-1]:6.2f} cm  floor {floor[-1]:5.2f} cm"
            T_true = true_sensor_poses(scenes, s) if args.true_sensors else None
            if T_true is not None:
                through_true.append(position_cm(est.estimate(T_true, images, backgrounds).best, truth))
                line += f"  through the true sensor poses {through_true[-1]:6.2f} cm"
            if best[-1] > args.wrong_cm:
                worse = refined.scores[0] > estimate.scores[0]
                scored_worse += int(worse)
                missed += int(not worse)
                line += (f"  truth scores {1000 * refined.scores[0]:.3f}, winner {1000 * estimate.scores[0]:.3f}: "
                         + ("the score prefers the wrong pose" if worse else "the search missed the truth"))
            print(line, flush=True)
        report = [summary("best pose", best), summary("floor", floor)]
        if through_true:
            report.append(summary("through the true sensor poses", through_true))
        print(f"{scene_set}: {len(best)} scenes; " + "; ".join(report) + f"; {scored_worse + missed} over "
              f"{args.wrong_cm:g} cm, the truth scoring worse in {scored_worse}, better in {missed}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
