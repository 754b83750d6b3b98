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

``--oracle-fit``: also the pose a search would start from if it knew where on the object each contact is:
each contact point as read (sensor frame) carried through the true sensor pose and the true object pose onto
the object, and the pose fitted from those object points to the contact points as read through the sensor
poses given (``oracle_fit``, the fast solver's weighted Kabsch with equal weights), then refined and scored
like the floor. ``--starts N``: N starts around each best pose (Gaussian, ``--start-mm`` and ``--start-deg``
per axis), refined and scored with it, the best kept: whether a wider local search would find a pose that
scores better and lies nearer the truth; with ``--average-tau MM`` also their score-weighted mean
(``weighted_pose_mean``): whether the refined starts scatter around the truth (their mean nearer it than the
best of them) or settle about a minimum of the score away from it (no nearer). The oracle fit needs L >= 3
contacts.

Per set it also counts the scenes whose refined true pose scores worse than the estimate's best pose: where
that is most scenes, the score's own minimum, not the search, sets the error.
A diagnostic: it changes nothing and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.geometry import invert_pose, make_pose, rotvec_to_rotmat, transform_points  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation import rank as rank_step  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.optimize import weighted_kabsch  # noqa: E402
from tactile6d.evaluation.kinematic_bound import true_sensor_poses  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def position_cm(T: np.ndarray, truth: np.ndarray) -> float:
    return float(100 * np.linalg.norm(T[:3, 3] - truth[:3, 3]))


def oracle_fit(T_world_sensors: np.ndarray, T_true_sensors: np.ndarray, T_world_object: np.ndarray,
               contact_points: np.ndarray) -> np.ndarray:
    """The pose fitted from the contacts' true places on the object to the contact points as read.

    T_world_sensors (L, 4, 4) as given, T_true_sensors (L, 4, 4) the true ones, T_world_object (4, 4) the true
    object pose, contact_points (L, 3) world, read through T_world_sensors -> (4, 4): each contact point in its
    sensor's frame, through the true sensor pose into the true object frame, then ``weighted_kabsch`` of those
    object points onto contact_points. With exact sensor poses that is the true pose."""
    T_world_sensors, T_true_sensors = np.asarray(T_world_sensors), np.asarray(T_true_sensors)
    in_sensor = [transform_points(invert_pose(T_world_sensors[i]), contact_points[i][None])[0]
                 for i in range(len(T_world_sensors))]
    on_object = np.stack([transform_points(invert_pose(T_world_object) @ T_true_sensors[i], p[None])[0]
                          for i, p in enumerate(in_sensor)])
    return weighted_kabsch(on_object[None], np.asarray(contact_points), np.ones((1, len(on_object))))[0]


def starts_around(T: np.ndarray, n: int, sigma_m: float, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """T (4, 4) and n poses around it (n + 1, 4, 4): T composed with Gaussian steps of sigma_m per axis of
    translation and sigma_rad per axis of rotation vector, in the object's frame."""
    steps = [make_pose(rotvec_to_rotmat(rng.normal(0.0, sigma_rad, 3)), rng.normal(0.0, sigma_m, 3)) for _ in range(n)]
    return np.stack([T] + [T @ step for step in steps])


def weighted_pose_mean(poses: np.ndarray, scores: np.ndarray, tau: float) -> np.ndarray:
    """The mean of poses (P, 4, 4) weighted by exp(-(score - best score) / tau), scores (P,) and tau in the
    same unit -> (4, 4): the weighted mean translation and the rotation nearest (Frobenius) the weighted mean of
    the rotation matrices (the chordal mean). A tau far below the scores' gaps gives the best pose."""
    w = np.exp(-(np.asarray(scores, dtype=np.float64) - np.min(scores)) / tau)
    w /= w.sum()
    U, _, Vt = np.linalg.svd(np.einsum("p,pij->ij", w, poses[:, :3, :3]))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return make_pose(R, w @ poses[:, :3, 3])


def refined_starts(est: Estimator, T_world_sensors: np.ndarray, starts: np.ndarray, contacts) -> rank_step.RefinedScores:
    """Every start (P, 4, 4) refined and scored as the ranking re-scores its candidates (``rank.refine_and_score``),
    none dropped as a duplicate (``Estimator.rank`` keeps the best distinct poses only)."""
    settings = est.settings.rank
    mesh = est.mesh if settings.uses_agreement and contacts.observed else None
    return rank_step.refine_and_score(est.penetration_model, est.surface, mesh, starts, np.asarray(T_world_sensors),
                                      contacts, settings, est.settings.sensors, int(settings.refine_iterations))


def summary(name: str, errors: list[float]) -> str:
    return f"{name} {np.mean(errors):.2f} cm (median {np.median(errors):.2f})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", required=True, help="scene sets (artifacts/scenes/<set>.h5)")
    parser.add_argument("--wrong-cm", type=float, default=1.0, help="a best pose this far from the truth is wrong")
    parser.add_argument("--true-sensors", action="store_true", help="also estimate through the true sensor poses")
    parser.add_argument("--oracle-fit", action="store_true",
                        help="also fit the contacts' true places on the object to the contacts as read, then refine")
    parser.add_argument("--starts", type=int, default=0, help="starts around each best pose, refined and scored with it")
    parser.add_argument("--start-mm", type=float, default=2.0, help="their spread per axis of translation (mm)")
    parser.add_argument("--start-deg", type=float, default=2.0, help="their spread per axis of rotation (deg)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the starts")
    parser.add_argument("--average-tau", type=float, default=None, metavar="MM",
                        help="with --starts: also the refined starts' mean, weighted exp(-(score - best) / tau)")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    if not cfg.rank.refine:
        raise SystemExit("the floor is the true pose refined as the ranking refines: needs rank.refine")
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        estimators: dict[str, Estimator] = {}
        best, floor, through_true, scored_worse, missed = [], [], [], 0, 0
        fitted, fitted_refined, widened, averaged, truth_worse = [], [], [], [], 0
        rng = np.random.default_rng(args.seed)
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
            truth_worse += int(refined.scores[0] > estimate.scores[0])
            line = f"{scene_set} {s:3d} {obj:22s} best {best[-1]:6.2f} cm  floor {floor[-1]:5.2f} cm"
            if args.oracle_fit:
                T_sensors = true_sensor_poses(scenes, s)
                fit = oracle_fit(T, T if T_sensors is None else T_sensors, truth, estimate.contacts.points)
                fitted.append(position_cm(fit, truth))
                fitted_refined.append(position_cm(est.rank(T, fit[None], np.zeros(1), estimate.contacts).poses[0], truth))
                line += f"  oracle fit {fitted[-1]:5.2f} cm, refined {fitted_refined[-1]:5.2f} cm"
            if args.starts > 0:
                starts = starts_around(estimate.best, args.starts, args.start_mm / 1000, np.radians(args.start_deg), rng)
                widened.append(position_cm(est.rank(T, starts, np.zeros(len(starts)), estimate.contacts).poses[0], truth))
                line += f"  best of {args.starts + 1} starts {widened[-1]:6.2f} cm"
                if args.average_tau is not None:
                    refined_all = refined_starts(est, T, starts, estimate.contacts)
                    mean = weighted_pose_mean(refined_all.poses, refined_all.scores, args.average_tau / 1000)
                    averaged.append(position_cm(mean, truth))
                    line += f", their weighted mean {averaged[-1]:6.2f} cm"
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
        if fitted:
            report += [summary("oracle fit", fitted), summary("oracle fit refined", fitted_refined)]
        if widened:
            report.append(summary(f"best of {args.starts + 1} starts", widened))
        if averaged:
            report.append(summary(f"their mean weighted at tau {args.average_tau:g} mm", averaged))
        if through_true:
            report.append(summary("through the true sensor poses", through_true))
        print(f"{scene_set}: {len(best)} scenes; " + "; ".join(report) + f"; {scored_worse + missed} over "
              f"{args.wrong_cm:g} cm, the truth scoring worse in {scored_worse}, better in {missed}; the refined "
              f"truth scores worse than the best pose in {truth_worse} of {len(best)}")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
