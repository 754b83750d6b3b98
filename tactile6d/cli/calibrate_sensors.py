"""``tactile6d calibrate-sensors``: each sensor's mounting offset, from grasps of known objects at known poses.

A hand's forward kinematics puts each fingertip off by millimetres and degrees, much of it usually a bias of
each finger's own (``tactile6d.estimation.sensor_offsets``). Grasp an object whose pose you know (a calibration
object in a fixture, or placed by a motion-capture rig) a few times, in different places, and record each
grasp as a scene folder in the paper's triplet layout (``poses_sensors.txt`` as the hand reports the sensor
poses, ``Image_heatmap_<i>.png``, optionally ``background_<i>.png``) with the object's known pose in
``object_pose.txt`` (one ``x y z ax ay az angle`` line, world frame, the same units as the sensor poses), or
give one pose for every scene with ``--object-pose FILE``. Each sensor's contact as read from its image
must then lie on the object's surface; the offset that makes it so (under the prior
``sensors.pose_sigma_mm``/``_deg``) is fitted per sensor and written to ``--out`` (JSON, default
``sensor_offsets.json``), which ``tactile6d estimate``, ``identify`` and ``track`` apply with
``--sensor-offsets FILE`` (``T_world_sensor @ offset``) before anything else, and the API's
``sensor_offsets.apply_sensor_offsets`` too.

Printed, per sensor: the offset (translation mm, rotation deg, in the sensor's frame), how far it moves the
gel's centre, in how many grasps the sensor touched, its contact points' RMS distance from the surface
before and after (mm), and what the grasps leave uncertain (one standard deviation of the gel centre's shift
along the sensor's axis and sideways: a press tells the first, a sideways slide over a smooth surface
looks like no slide, so the second often stays near the prior; a note says so). A sensor that touched in no grasp keeps no offset, with
a warning. Objects, artifacts, ``--background``, ``--known-units`` and config overrides as ``tactile6d estimate``:
the grasps' images are read as it reads them.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tactile6d.cli import description
from tactile6d.cli.estimate import (AUTO, FROM_SCENES, EstimatorCache, add_known_units_argument, add_scene_arguments,
                                    background_option, collect_scenes, known_units_option, object_of,
                                    read_scene_folder, split_overrides, warnings_to_lines, write)
from tactile6d.cli.objects import KnownObjects
from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.core.geometry import line_to_pose
from tactile6d.perception import photometric

if TYPE_CHECKING:
    from tactile6d.estimation.sensor_offsets import KnownGrasp, SensorOffsets

OBJECT_POSE_FILE = "object_pose.txt"
# Fewer grasps than this leave most of an offset to its prior: said, not refused.
FEW_GRASPS = 3


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="tactile6d calibrate-sensors",
        description=description(__doc__),
        usage=("tactile6d calibrate-sensors --object NAME|auto --scene DIR [DIR ...] [--object-pose FILE] "
               "[--out FILE] [options] [key=value ...]"),
    )
    add_scene_arguments(parser, "grasp", f"poses_sensors.txt, Image_heatmap_<i>.png, {OBJECT_POSE_FILE}")
    parser.add_argument("--object-pose", default=None, metavar="FILE",
                        help=f"the object's known pose for every grasp (one 'x y z ax ay az angle' line); "
                             f"default: each grasp folder's {OBJECT_POSE_FILE}")
    parser.add_argument("--out", default="sensor_offsets.json", metavar="FILE", help="where the offsets go (JSON)")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--background", nargs="+", default=None, metavar="PNG",
                        help="the sensors' own no-contact image(s): one for every sensor or one per sensor, or "
                             f"'{FROM_SCENES}' (estimated from the grasps' images) as for `tactile6d estimate` "
                             "(default: each grasp folder's background_<i>.png, else render.background)")
    add_known_units_argument(parser)
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    args = parser.parse_args(argv)
    args.scene, moved = split_overrides(args.scene, [])
    args.background, args.overrides = split_overrides(args.background, moved + list(args.overrides))
    args.known_units, args.overrides = split_overrides(args.known_units, list(args.overrides))
    if not args.scene and args.scenes_root is None:
        parser.error("give --scene DIR [DIR ...] or --scenes-root DIR")
    return args


def read_pose_file(path: Path) -> np.ndarray:
    """A file of one ``x y z ax ay az angle`` line -> (4, 4); InputError naming the file."""
    try:
        lines = [line for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    except OSError as exc:
        raise InputError(f"{path}: cannot read the object's pose ({exc.strerror or exc})") from None
    if len(lines) != 1:
        raise InputError(f"{path}: expected one 'x y z ax ay az angle' line (the object's pose), got {len(lines)}")
    try:
        return line_to_pose(lines[0])
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None


def object_pose_of(scene: Path, given: np.ndarray | None) -> np.ndarray:
    """The grasp's known object pose: ``--object-pose``'s, else the folder's ``object_pose.txt``."""
    if given is not None:
        return given
    path = scene / OBJECT_POSE_FILE
    if not path.is_file():
        raise InputError(f"{scene}: no {OBJECT_POSE_FILE} (the object's known pose in this grasp); write it, or "
                         "give one pose for every grasp with --object-pose FILE")
    return read_pose_file(path)


def read_grasp(scene: Path, name: str, cache: EstimatorCache, T_world_object: np.ndarray) -> KnownGrasp:
    """One grasp: its images read as ``tactile6d estimate`` reads them (``Estimator.read_scene``: brought to their
    no-contact images' light; without one of their own, read against the known unit's they agree with)."""
    from tactile6d.estimation.sensor_offsets import KnownGrasp  # the estimator's modules: not loaded for --help

    T_world_sensors, images, backgrounds, lines = read_scene_folder(scene, cache.background is not None)
    for line in lines:
        write(line, sys.stderr)
    estimator = cache.load(name)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", photometric.LightWarning)
        T, contacts = estimator.read_scene(T_world_sensors, images, backgrounds)
    for line in warnings_to_lines(scene, caught):
        write(line, sys.stderr)
    return KnownGrasp(estimator.surface, T_world_object, T, contacts)


def report(offsets: SensorOffsets, out: Path, prior_gel_sigma: np.ndarray) -> str:
    """The table printed after the fit: per sensor its offset, how far it moves the gel centre, the contact
    points' distance from the surface before and after, and what the grasps left uncertain (prior_gel_sigma
    (3,) m: what the prior alone leaves, ``sensor_offsets.prior_sigmas``)."""
    from tactile6d.estimation.sensor_offsets import gel_centre_shifts

    t, r = offsets.translations_mm(), offsets.rotations_deg()
    moved = gel_centre_shifts(offsets.offsets)
    along, sideways = 1000 * offsets.gel_sigma_m[:, 0], 1000 * offsets.gel_sigma_m[:, 1:].max(axis=1)
    lines = [f"sensor offsets written to {out} (T_world_sensor @ offset, in the sensor's frame)",
             f"{'sensor':>6}  {'grasps':>6}  {'translation (mm)':<20}  {'rotation (deg)':<20}  {'gel moved':>9}  "
             f"{'off the surface (RMS)':<21}  uncertain (1 sigma): gel along the axis, sideways"]
    for i in range(offsets.n_sensors):
        if offsets.grasps[i] == 0:
            lines.append(f"{i:>6}  {0:>6}  no contact read in any grasp: no offset")
            continue
        lines.append(
            f"{i:>6}  {offsets.grasps[i]:>6}  {t[i, 0]:+6.2f}{t[i, 1]:+7.2f}{t[i, 2]:+7.2f}  "
            f"{r[i, 0]:+6.2f}{r[i, 1]:+7.2f}{r[i, 2]:+7.2f}  {1000 * np.linalg.norm(moved[i]):6.2f} mm  "
            f"{offsets.residual_before_mm[i]:5.2f} -> {offsets.residual_mm[i]:4.2f} mm{'':6}  "
            f"{along[i]:.2f} mm, {sideways[i]:.2f} mm")
    if np.any(sideways[offsets.grasps > 0] > 0.5 * 1000 * prior_gel_sigma[1:].max()):
        lines.append("note: a press tells a sensor's offset along its axis; a sideways one shows only where the "
                     "surface under the gel changes shape (edges, corners, rims): grasp there too to pin it down")
    lines.append(f"use: tactile6d estimate ... --sensor-offsets {out}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    cfg = compose_config(list(args.overrides))
    from tactile6d.estimation.sensor_offsets import fit_sensor_offsets, prior_sigmas

    if cfg.sensors.pose_sigma_mm <= 0 or cfg.sensors.pose_sigma_deg <= 0:
        raise InputError("calibrate-sensors needs the hand's expected error as its prior: sensors.pose_sigma_mm "
                         "and sensors.pose_sigma_deg > 0")
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    known = KnownObjects(artifacts, cfg)
    if args.object != AUTO:
        known.get(args.object)
    given_pose = read_pose_file(Path(args.object_pose)) if args.object_pose else None
    scenes = collect_scenes(args)
    cache = EstimatorCache(known, cfg, background_option(args.background, scenes),
                           known_units=known_units_option(args.known_units, args.background))
    grasps = [read_grasp(scene, object_of(scene, args.object, known), cache, object_pose_of(scene, given_pose))
              for scene in scenes]
    rank, sigma_m, sigma_rad = cfg.rank, 1e-3 * cfg.sensors.pose_sigma_mm, np.radians(cfg.sensors.pose_sigma_deg)
    offsets = fit_sensor_offsets(grasps, sigma_m, sigma_rad, float(rank.refine_normal_weight),
                                 int(rank.refine_patch_points), float(rank.refine_patch_weight))
    offsets = replace(offsets, notes={"grasps": [str(s) for s in scenes], "object": args.object,
                                      "pose_sigma_mm": float(cfg.sensors.pose_sigma_mm),
                                      "pose_sigma_deg": float(cfg.sensors.pose_sigma_deg)})
    out = Path(args.out)
    offsets.write(out)
    for i in np.flatnonzero(offsets.grasps < FEW_GRASPS):
        write(f"warning: sensor {i} touched in {offsets.grasps[i]} grasp(s): "
              + ("it keeps no offset" if offsets.grasps[i] == 0 else "its offset rests mostly on the prior")
              + f"; grasp at least {FEW_GRASPS} times, in different places", sys.stderr)
    write(report(offsets, out, prior_sigmas(sigma_m, sigma_rad)[0]), sys.stdout)
    return 0
