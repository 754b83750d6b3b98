"""What calibrating a hand's sensor offsets buys: grasps of known objects at known poses, then unknown ones.

    python scripts/sensor_offsets_study.py --artifacts ART --calibration CAL.h5 --test TEST.h5 [--hands 3]
        [--bias-mm 1.5 --bias-deg 1.5 --jitter-mm 0.1 --jitter-deg 0.1] [--grasps 10] [--seed 0] [override ...]
    python scripts/sensor_offsets_study.py --artifacts ART --calibration CAL.h5 --sequences tracking.h5
    python scripts/sensor_offsets_study.py ... --test TEST.h5 --self [--rounds 8] [--grasps 20]
    python scripts/sensor_offsets_study.py --artifacts ART --calibration CAL.h5 --write-grasps DIR

CAL.h5 and TEST.h5 are two generated scene sets of their own seeds (``make_scenes``' ``scenes`` files, e.g. the
validation kind with ``scenes.validation.seed=...``). For each of ``--hands`` simulated hands, each sensor (by
its place in the sensor order) gets a bias of its own, drawn once (Gaussian, ``--bias-mm`` and ``--bias-deg``
per axis in the sensor's frame), and every scene a jitter on top (``--jitter-*``): the sensor poses the hand
reports are the true ones moved by both, the images those of the true poses. The first ``--grasps`` scenes of
CAL are the calibration: their object poses known, ``sensor_offsets.fit_sensor_offsets`` fits each sensor's
offset (prior: the config's ``sensors`` sigmas). Every scene of TEST is then estimated (default estimator,
images and no-contact images) through

- the poses as reported (``sensors`` as configured),
- the reported poses corrected by the fitted offsets (``sensors`` as configured),
- the same, with ``sensors.pose_sigma_mm``/``_deg`` lowered to ``--after-mm``/``--after-deg``,
- the true poses (what an exact hand would give; ``sensors`` as configured).

``--self`` (an experiment, not a command): no object pose known; the CAL scenes are estimated through the
poses as corrected so far, the confident estimates' best poses (``--self-confidence``, not ambiguous) taken for
known and the offsets refitted, ``--rounds`` times. ``--sequences FILE``: each sequence of a ``make_sequences``
file calibrated for its own bias from the CAL grasps, then tracked through the poses as reported, corrected and
true (median and mean error over frames, the longest run over 2 cm); with ``--surface-penetration`` the tracker
(its updates and re-detections) scores penetration with the object's surface samples instead of its convex pieces
(``scripts/surface_penetration.py``; docs/collision.md).

``--write-grasps DIR`` only writes the first hand's calibration grasps as scene folders (with object_pose.txt),
as ``tactile6d calibrate-sensors`` reads them.

Printed per hand: the gel centres' shift under the bias and under what the offsets leave of it (mm per sensor,
along its axis and sideways), the offsets' posterior sigmas, the contact residuals before and after, and each
row's positional error #1, mean (median) cm, with how many scenes are 1 cm or more off. A diagnostic: it writes
nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.geometry import make_pose, pose_to_line, poses_to_text, rotvec_to_rotmat  # noqa: E402
from tactile6d.data.hdf5 import read_artifact, write_tactile_image  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.sensor_offsets import (KnownGrasp, apply_sensor_offsets, fit_sensor_offsets,  # noqa: E402
                                                 gel_centre_shifts)
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def draw_errors(shape: tuple[int, ...], sigma_m: float, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """(*shape, 4, 4) pose errors, Gaussian per axis in the sensor's frame."""
    return make_pose(rotvec_to_rotmat(rng.normal(0.0, sigma_rad, shape + (3,)).reshape(-1, 3)),
                     rng.normal(0.0, sigma_m, shape + (3,)).reshape(-1, 3)).reshape(shape + (4, 4))


def gel_shift_mm(error: np.ndarray) -> np.ndarray:
    """(..., 4, 4) sensor-frame errors -> how far each moves the gel centre, mm."""
    return 1000.0 * np.linalg.norm(gel_centre_shifts(error), axis=-1)


def axial_and_sideways_mm(error: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(L, 4, 4) sensor-frame errors -> the gel centre's shift along each sensor's axis (x) and sideways (y, z), mm."""
    moved = gel_centre_shifts(error)
    return 1000.0 * np.abs(moved[:, 0]), 1000.0 * np.linalg.norm(moved[:, 1:], axis=1)


def summary(errors: list[float]) -> str:
    e = np.asarray(errors)
    return f"{e.mean():.2f} ({np.median(e):.2f}) cm, {int(np.sum(e >= 1.0))} of {len(e)} over 1 cm"


class Estimators:
    """One estimator per (object, settings)."""

    def __init__(self, artifacts: str, cfgs: dict):
        self.artifacts, self.cfgs, self.cache = artifacts, cfgs, {}

    def get(self, obj: str, which: str) -> Estimator:
        if (obj, which) not in self.cache:
            self.cache[obj, which] = Estimator.from_artifacts(obj, self.artifacts, self.cfgs[which])
        return self.cache[obj, which]


def write_grasps(cal, n_grasps: int, bias: np.ndarray, args, rng, root: Path) -> list[Path]:
    """The first ``n_grasps`` scenes of ``cal`` seen through ``bias`` and a jitter, written as grasp folders
    ``root/<object>/grasp_<k>`` for ``tactile6d calibrate-sensors``: poses_sensors.txt as the hand reports them,
    Image_heatmap_<i>.png, object_pose.txt (and background_<i>.png when the set has its own)."""
    L, folders = len(bias), []
    for s in range(n_grasps):
        folder = root / str(cal["objects"][s]) / f"grasp_{s}"
        folder.mkdir(parents=True)
        error = bias @ draw_errors((L,), 1e-3 * args.jitter_mm, np.radians(args.jitter_deg), rng)
        (folder / "poses_sensors.txt").write_text(poses_to_text(np.asarray(cal["T_world_sensors"][s]) @ error))
        (folder / "object_pose.txt").write_text(pose_to_line(np.asarray(cal["T_world_object"][s])) + "\n")
        backgrounds = scene_backgrounds(cal, s)
        for i in range(L):
            write_tactile_image(folder / f"Image_heatmap_{i}.png", np.asarray(cal["images"][s][i]))
            if backgrounds is not None:
                write_tactile_image(folder / f"background_{i}.png", backgrounds[i])
        folders.append(folder)
    return folders


def calibrate(cal, n_grasps: int, bias: np.ndarray, args, estimators: Estimators, cfg, rng):
    """The offsets fitted from the first ``n_grasps`` scenes of ``cal`` seen through ``bias`` and a jitter."""
    L = len(bias)
    grasps = []
    for s in range(n_grasps):
        obj = str(cal["objects"][s])
        error = bias @ draw_errors((L,), 1e-3 * args.jitter_mm, np.radians(args.jitter_deg), rng)
        reported = np.asarray(cal["T_world_sensors"][s]) @ error
        est = estimators.get(obj, "default")
        contacts = est.contacts(reported, cal["images"][s], scene_backgrounds(cal, s))
        grasps.append(KnownGrasp(est.surface, np.asarray(cal["T_world_object"][s]), reported, contacts))
    sigma_m, sigma_rad = 1e-3 * cfg.sensors.pose_sigma_mm, np.radians(cfg.sensors.pose_sigma_deg)
    return fit_sensor_offsets(grasps, sigma_m, sigma_rad, cfg.rank.refine_normal_weight,
                              int(cfg.rank.refine_patch_points), float(cfg.rank.refine_patch_weight))


def self_calibrate(cal, n_grasps: int, bias: np.ndarray, args, estimators: Estimators, cfg, rng):
    """The offsets fitted without knowing any object pose: the first ``n_grasps`` scenes of ``cal`` estimated
    through the poses as corrected so far, their confident best poses taken for known, the offsets refitted;
    ``args.rounds`` times. -> (offsets (L, 4, 4) composed over the rounds, the scenes used in the last)."""
    L = len(bias)
    reported = [np.asarray(cal["T_world_sensors"][s]) @ bias @ draw_errors((L,), 1e-3 * args.jitter_mm,
                                                                           np.radians(args.jitter_deg), rng)
                for s in range(n_grasps)]
    sigma_m, sigma_rad = 1e-3 * cfg.sensors.pose_sigma_mm, np.radians(cfg.sensors.pose_sigma_deg)
    total = np.repeat(np.eye(4)[None], L, axis=0)
    for _ in range(args.rounds):
        grasps = []
        for s in range(n_grasps):
            obj = str(cal["objects"][s])
            est = estimators.get(obj, "default")
            T = apply_sensor_offsets(reported[s], total)
            result = est.estimate(T, cal["images"][s], scene_backgrounds(cal, s))
            if result.confidence is not None and result.confidence >= args.self_confidence and not result.ambiguous:
                grasps.append(KnownGrasp(est.surface, result.best, T, result.contacts))
        step = fit_sensor_offsets(grasps, sigma_m, sigma_rad, cfg.rank.refine_normal_weight,
                                  int(cfg.rank.refine_patch_points), float(cfg.rank.refine_patch_weight))
        total = total @ step.offsets
    return replace_offsets(step, total), len(grasps)


def replace_offsets(offsets, total: np.ndarray):
    from dataclasses import replace

    return replace(offsets, offsets=total)


def describe(label: str, bias: np.ndarray, offsets) -> str:
    before, after = axial_and_sideways_mm(bias), axial_and_sideways_mm(bias @ offsets.offsets)
    return (f"{label}: the bias moves each gel centre {gel_shift_mm(bias).round(2)} mm (along the sensor's "
            f"axis {before[0].round(2)}, sideways {before[1].round(2)}); after the offsets "
            f"{gel_shift_mm(bias @ offsets.offsets).round(2)} mm (along {after[0].round(2)}, sideways "
            f"{after[1].round(2)}); posterior sigma of the gel along the axis "
            f"{np.round(1000 * offsets.gel_sigma_m[:, 0], 2)} mm, sideways "
            f"{np.round(1000 * offsets.gel_sigma_m[:, 1:].max(axis=1), 2)} mm; contact residual RMS "
            f"{offsets.residual_before_mm.round(2)} -> {offsets.residual_mm.round(2)} mm; grasps {offsets.grasps}")


def track_sequences(path: str, cal, n_grasps: int, args, estimators: Estimators, cfg, rng) -> None:
    """Each sequence's hand bias (drawn by make_sequences) calibrated from the CAL grasps, then the sequence tracked
    through the poses as reported, corrected and true: median (mean) positional error over frames, and the
    longest run over 2 cm."""
    from dataclasses import replace

    from tactile6d.estimation.tracker import Tracker, TrackSettings
    from tactile6d.evaluation.tracking_accuracy import longest_over, track_frames

    from surface_penetration import penetration_of  # scripts/, this script's folder

    seqs = read_artifact(path, "sequences")
    fps = float(np.asarray(seqs["fps"]).reshape(-1)[0])
    pooled = {k: [] for k in ("reported", "corrected", "true")}
    for q in range(len(seqs["names"])):
        obj, truth = str(seqs["objects"][q]), np.asarray(seqs["T_world_object"][q])
        bias = make_pose(rotvec_to_rotmat(np.asarray(seqs["pose_bias_rotvec"][q])),
                         np.asarray(seqs["pose_bias_translation"][q]))
        offsets = calibrate(cal, n_grasps, bias, args, estimators, cfg, rng)
        print(describe(f"sequence {q} ({obj})", bias, offsets), flush=True)
        reported, images = np.asarray(seqs["T_world_sensors"][q]), np.asarray(seqs["images"][q])
        for key, T in (("reported", reported), ("corrected", apply_sensor_offsets(reported, offsets)),
                       ("true", np.asarray(seqs["T_world_sensors_true"][q]))):
            estimator = estimators.get(obj, "default")
            settings = replace(TrackSettings.from_cfg(cfg.track), threads=1)
            with penetration_of(estimator, args.surface_penetration), Tracker(estimator, settings) as tracker:
                poses = np.stack([a.pose for a in track_frames(tracker.update, T, images)])
            error = 100 * np.linalg.norm(poses[:, :3, 3] - truth[:, :3, 3], axis=1)
            pooled[key].append(error)
            print(f"sequence {q} ({obj}) {key:10s} {np.nanmedian(error):.2f} ({np.nanmean(error):.2f}) cm, longest "
                  f"over 2 cm {longest_over(error / 100, 0.02, fps):.2f} s", flush=True)
    for key, e in pooled.items():
        longest = max(longest_over(x / 100, 0.02, fps) for x in e)
        e = np.concatenate(e)
        print(f"all sequences: {key:10s} {np.nanmedian(e):.2f} ({np.nanmean(e):.2f}) cm, longest over 2 cm {longest:.2f} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", required=True)
    parser.add_argument("--calibration", required=True, help="scenes file whose first --grasps scenes calibrate")
    parser.add_argument("--test", default=None, help="scenes file estimated after the calibration")
    parser.add_argument("--sequences", default=None, help="sequences file (make_sequences) tracked after it")
    parser.add_argument("--surface-penetration", action="store_true",
                        help="with --sequences: the tracker scores penetration with the surface, not the pieces")
    parser.add_argument("--grasps", type=int, default=10)
    parser.add_argument("--hands", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--bias-mm", type=float, default=1.5)
    parser.add_argument("--bias-deg", type=float, default=1.5)
    parser.add_argument("--jitter-mm", type=float, default=0.1)
    parser.add_argument("--jitter-deg", type=float, default=0.1)
    parser.add_argument("--self", action="store_true", dest="self_calibrate",
                        help="fit the offsets from the CAL scenes' own estimates, no object pose known")
    parser.add_argument("--rounds", type=int, default=3, help="with --self: estimate-and-refit rounds")
    parser.add_argument("--self-confidence", type=float, default=0.9, help="with --self: the estimates kept")
    parser.add_argument("--write-grasps", default=None, metavar="DIR",
                        help="only write the first hand's calibration grasps as scene folders under DIR")
    parser.add_argument("--after-mm", type=float, default=0.5)
    parser.add_argument("--after-deg", type=float, default=0.5)
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args(argv)
    cfg = compose_config(args.overrides)
    cfgs = {"default": cfg, "after": compose_config(args.overrides + [f"sensors.pose_sigma_mm={args.after_mm}",
                                                                       f"sensors.pose_sigma_deg={args.after_deg}"])}
    estimators = Estimators(args.artifacts, cfgs)
    cal = read_artifact(args.calibration, "scenes")
    n_cal, L = min(args.grasps, len(cal["names"])), int(np.asarray(cal["T_world_sensors"]).shape[1])
    rng = np.random.default_rng(args.seed)
    if args.write_grasps:
        bias = draw_errors((L,), 1e-3 * args.bias_mm, np.radians(args.bias_deg), rng)
        folders = write_grasps(cal, n_cal, bias, args, rng, Path(args.write_grasps))
        print(f"{len(folders)} grasp folders under {args.write_grasps}")
        return 0
    if args.sequences:
        track_sequences(args.sequences, cal, n_cal, args, estimators, cfg, rng)
    if not args.test:
        return 0
    test = read_artifact(args.test, "scenes")
    rows = {k: [] for k in ("reported", "corrected", "corrected, sigmas lowered", "true")}
    for hand in range(args.hands):
        bias = draw_errors((L,), 1e-3 * args.bias_mm, np.radians(args.bias_deg), rng)
        if args.self_calibrate:
            offsets, used = self_calibrate(cal, n_cal, bias, args, estimators, cfg, rng)
            print(f"hand {hand}: {used} of {n_cal} estimates confident enough in the last round", flush=True)
        else:
            offsets = calibrate(cal, n_cal, bias, args, estimators, cfg, rng)
        print(describe(f"hand {hand}", bias, offsets), flush=True)
        errors = {k: [] for k in rows}
        for s in range(len(test["names"])):
            obj, truth = str(test["objects"][s]), np.asarray(test["T_world_object"][s])
            true_T = np.asarray(test["T_world_sensors"][s])
            reported = true_T @ bias @ draw_errors((L,), 1e-3 * args.jitter_mm, np.radians(args.jitter_deg), rng)
            images, backgrounds = test["images"][s], scene_backgrounds(test, s)
            corrected = apply_sensor_offsets(reported, offsets)
            for key, T, which in (("reported", reported, "default"), ("corrected", corrected, "default"),
                                  ("corrected, sigmas lowered", corrected, "after"), ("true", true_T, "default")):
                best = estimators.get(obj, which).estimate(T, images, backgrounds).best
                errors[key].append(float(100 * np.linalg.norm(best[:3, 3] - truth[:3, 3])))
        for key, e in errors.items():
            rows[key] += e
            print(f"hand {hand}: {key:26s} {summary(e)}", flush=True)
    for key, e in rows.items():
        print(f"all hands: {key:26s} {summary(e)}")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
