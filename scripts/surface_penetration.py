"""Would the ranking choose better if it measured penetration against the object's real surface?

    python scripts/surface_penetration.py --artifacts artifacts --scenes validation kinematic [override ...]
    python scripts/surface_penetration.py --artifacts artifacts --sequences [--true-sensors] [override ...]

The ranking's re-scoring (``rank.rank``) charges each refined candidate for its deepest penetration into a
DIGIT body, measured with the object's convex pieces, which bury part of a concave object's surface under
millimetres of excess (``scripts/collision_excess.py``). This estimates every scene of the sets twice with the
default estimator: as it is, and with the re-scored candidates' penetration measured instead from the object's
surface samples (``surface_sampling.sample_surface``, 1 mm apart): the deepest sample inside each sensor's box,
through the corrected sensor poses as the ranking uses them. The first ranking (branch and bound over every
hypothesis) keeps the pieces either way. Prints per set the positional error of the best pose, mean (median)
cm, and how many are over 1 cm off, for both; then, over all scenes, the mean paired difference (surface minus
pieces) with a bootstrap 90 % interval.

``--sequences``: the tracking sequences instead (``artifacts/sequences/tracking.h5``, stage make_sequences), each
followed by the tracker (``Tracker.update`` frame by frame, as stage evaluate_tracking follows them), whose
updates score their refined poses with ``rank.seen_penetrations`` too, once with the pieces and once with the
surface; through the sensor poses as the hand reports them, or with ``--true-sensors`` the true ones. Prints per
sequence and pooled the tracked positional error's median and mean (cm) and the longest run of frames over 2 cm
(s), for both. A diagnostic: it swaps ``rank.seen_penetrations`` for the run and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

import tactile6d.estimation.rank as rank_module  # noqa: E402
from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.geometry import invert_pose  # noqa: E402
from tactile6d.core.sensor import BOX_HALF_EXTENTS  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation import collision  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.optimize import use_cpu_devices_for  # noqa: E402
from tactile6d.estimation.tracker import Tracker, TrackSettings  # noqa: E402
from tactile6d.evaluation import scoring  # noqa: E402
from tactile6d.evaluation import tracking_accuracy as accuracy  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

_BOX_RADIUS = float(np.linalg.norm(BOX_HALF_EXTENTS))


def surface_to_box_depths(surface, T_world_object: np.ndarray, T_world_sensors: np.ndarray) -> np.ndarray:
    """surface: samples (``points`` (S, 3), ``tree``) in the object frame; T_world_object (P, 4, 4);
    T_world_sensors (L, 4, 4) -> (P, L) m: the deepest surface sample inside each sensor's box (0 if none)."""
    T_world_object = np.asarray(T_world_object, dtype=np.float64).reshape(-1, 4, 4)
    boxes = collision.sensor_box_poses(T_world_sensors)
    depths = np.zeros((len(T_world_object), len(boxes)))
    for p, T in enumerate(T_world_object):
        T_object_box = invert_pose(T)[None] @ boxes
        for i, box in enumerate(T_object_box):
            near = surface.tree.query_ball_point(box[:3, 3], _BOX_RADIUS)
            if near:
                local = (surface.points[near] - box[:3, 3]) @ box[:3, :3]
                depths[p, i] = collision.box_point_depth(local, BOX_HALF_EXTENTS).max()
    return depths


def penetration_of(estimator: Estimator, surface: bool):
    """A context in which the estimator's ranking and tracker measure penetration with its surface samples
    (``surface``) or, as they do, with its convex pieces."""
    if not surface:
        return nullcontext()
    return surface_penetration({id(estimator.penetration_model): estimator.surface})


@contextmanager
def surface_penetration(surfaces: dict[int, object]):
    """For the duration, the ranking's re-scoring measures penetration with ``surface_to_box_depths``
    (surfaces: id of an estimator's PenetrationModel -> its surface samples)."""
    original = rank_module.seen_penetrations

    def seen_penetrations(model, seen, T_world_sensors):
        surface = surfaces[id(model)]
        return np.stack([surface_to_box_depths(surface, seen[:, i], T_world_sensors[i : i + 1])[:, 0]
                         for i in range(len(T_world_sensors))], axis=1)

    rank_module.seen_penetrations = seen_penetrations
    try:
        yield
    finally:
        rank_module.seen_penetrations = original


def track_sequences(artifacts: str, cfg, true_sensors: bool) -> None:
    """Every tracking sequence followed with the pieces' penetration and with the surface's; prints each
    sequence's and the pooled tracked positional error, median (mean) cm, and the longest run over 2 cm (s)."""
    seq = read_artifact(layout.sequences_file(artifacts, "tracking"), "sequences")
    fps = float(np.asarray(seq["fps"]).reshape(-1)[0])
    lost = float(cfg.track.evaluation.lost_threshold)
    poses = "T_world_sensors_true" if true_sensors else "T_world_sensors"
    settings = TrackSettings.from_cfg(cfg.track)
    pooled = {"pieces": [], "surface": []}
    for q in range(len(seq["objects"])):
        obj = str(seq["objects"][q])
        estimator = Estimator.from_artifacts(obj, artifacts, cfg)
        reference = scoring.load_object_reference(artifacts, obj)
        truth, line = np.asarray(seq["T_world_object"][q]), f"{seq['names'][q]}:"
        for mode in pooled:
            with penetration_of(estimator, mode == "surface"), Tracker(estimator, settings) as tracker:
                answers = accuracy.track_frames(tracker.update, np.asarray(seq[poses][q]), np.asarray(seq["images"][q]))
            error = accuracy.pose_errors(reference.points, np.stack([a.pose for a in answers]), truth,
                                         reference.tree)["position"]
            pooled[mode].append(error)
            line += (f"  {mode} {100 * np.nanmedian(error):.2f} ({100 * np.nanmean(error):.2f}) cm, "
                     f"longest over {100 * lost:g} cm {accuracy.longest_over(error, lost, fps):.2f} s")
        print(line, flush=True)
    for mode, errors in pooled.items():
        e = np.concatenate(errors)
        longest = max(accuracy.longest_over(x, lost, fps) for x in errors)
        print(f"all {len(e)} frames, {mode}: {100 * np.nanmedian(e):.2f} ({100 * np.nanmean(e):.2f}) cm, longest over "
              f"{100 * lost:g} cm {longest:.2f} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--scenes", nargs="+", help="scene sets (artifacts/scenes/<set>.h5)")
    which.add_argument("--sequences", action="store_true", help="the tracking sequences, tracked")
    parser.add_argument("--true-sensors", action="store_true", help="with --sequences: through the true sensor poses")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    if cfg.sensors.pose_sigma_mm == 0 and cfg.sensors.pose_sigma_deg == 0:
        raise SystemExit("with the sensor poses declared exact the ranking scores no corrected sensors: nothing to swap")
    if args.sequences:
        # JAX's host devices as stage evaluate_tracking sets them, so that the pieces' runs are the stage's
        use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
        track_sequences(args.artifacts, cfg, args.true_sensors)
        return 0
    estimators, surfaces, pooled = {}, {}, {"pieces": [], "surface": []}
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        errors = {"pieces": [], "surface": []}
        for s in range(len(scenes["names"])):
            obj = str(scenes["objects"][s])
            if obj not in estimators:
                estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
                surfaces[id(estimators[obj].penetration_model)] = estimators[obj].surface
            for mode in errors:
                with surface_penetration(surfaces) if mode == "surface" else nullcontext():
                    best = estimators[obj].estimate(scenes["T_world_sensors"][s], scenes["images"][s],
                                                    scene_backgrounds(scenes, s)).best
                errors[mode].append(100 * float(np.linalg.norm(best[:3, 3] - scenes["T_world_object"][s][:3, 3])))
        for mode, e in errors.items():
            e = np.array(e)
            pooled[mode].extend(e)
            print(f"{scene_set:12s} {mode:8s} {e.mean():.3f} ({np.median(e):.3f}) cm, {int((e > 1).sum())} over 1 cm",
                  flush=True)
    difference = np.array(pooled["surface"]) - np.array(pooled["pieces"])
    means = np.random.default_rng(0).choice(difference, (10000, len(difference))).mean(axis=1)
    print(f"all {len(difference)} scenes: surface minus pieces {difference.mean():+.3f} cm "
          f"[{np.percentile(means, 5):+.3f}, {np.percentile(means, 95):+.3f}], {int((difference != 0).sum())} scenes changed")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
