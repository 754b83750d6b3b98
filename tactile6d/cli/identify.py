"""``tactile6d identify``: which object of a library touches the sensors, and its pose.

One scene folder in the paper's triplet layout (``poses_sensors.txt`` + ``Image_heatmap_<i>.png``, as
for ``tactile6d estimate``) against the objects given with ``--objects`` (default: every object with
artifacts in the artifacts directory, every distractor with artifacts in its ``distractors/``
folder, ``identify.distractors``, and every one of your own objects with artifacts in ``own/``). The
images are read once; every object is estimated on them and scored with the weights the
``calibrate_identify`` stage fitted on the calibration scenes (``identify.calibration_scenes``;
``tactile6d.estimation.identifier``). Output: one line per object, most probable first, with its probability,
score and best pose (``x y z ax ay az angle``, world frame), objects that match nothing last; then the
time per step. ``--json``: one JSON object (``Identification.to_dict``). Errors: one ``error:`` line and
exit status 2; objects without artifacts are all named in that one line. The sensors' no-contact images:
``--background`` (one file for every sensor, or one per sensor in sensor order), else the scene folder's
``background_<i>.png`` when it holds them (said on stderr), else ``render.background``; as for
``tactile6d estimate``, one sensor only gives a ``warning:`` line. ``--sensor-offsets FILE`` corrects the sensor
poses by the hand's offsets (``tactile6d calibrate-sensors``) first.

Config overrides (``key=value``) pass through, e.g. ``identify.screen.N=1000`` or
``identify.weights=[1,1,10]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from tactile6d.cli import description
from tactile6d.cli.estimate import (add_sensor_offsets_argument, is_override, one_scene_background_option,
                                    read_sensor_offsets, scene_backgrounds, split_overrides, use_solver_devices,
                                    warnings_to_lines)
from tactile6d.cli.objects import KnownObjects
from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.core.geometry import pose_to_line
from tactile6d.data.hdf5 import read_scene_dir
from tactile6d.perception.inputs import UnderdeterminedPoseWarning
from tactile6d.perception.photometric import LightWarning

if TYPE_CHECKING:
    from tactile6d.estimation.identifier import Identification


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="tactile6d identify", description=description(__doc__),
        usage="tactile6d identify --scene DIR [--objects NAME ...] [options] [key=value ...]")
    parser.add_argument("--scene", required=True, metavar="DIR",
                        help="scene folder: poses_sensors.txt + Image_heatmap_<i>.png")
    parser.add_argument("--objects", nargs="+", default=None, metavar="NAME",
                        help="the candidate objects (default: every object with artifacts)")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--background", nargs="+", default=None, metavar="PNG",
                        help="the sensors' own no-contact image(s) (PNG, 240 x 320): one for every sensor or one "
                             "per sensor in sensor order; default: the scene's background_<i>.png, else "
                             "render.background")
    add_sensor_offsets_argument(parser, "poses_sensors.txt's poses")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    args = parser.parse_args(argv)
    args.background, args.overrides = split_overrides(args.background, list(args.overrides))
    if args.objects:  # ``--objects A B select.N=5`` puts the override among the names
        args.overrides = [w for w in args.objects if is_override(w)] + list(args.overrides)
        args.objects = [w for w in args.objects if not is_override(w)]
    return args


def as_text(result: Identification) -> str:
    """One line per object, most probable first, then the time per step."""
    lines = []
    for rank, obj in enumerate(result.objects, start=1):
        if obj.pose is None:
            lines.append(f"{rank:>3}. {obj.name}: no match ({obj.candidate.why})")
        else:
            refined = " (full estimate)" if rank == 1 and result.refined else ""
            lines.append(f"{rank:>3}. {obj.name}: p {obj.probability:.3f}, score {obj.score:.3f}; "
                         f"pose{refined} {pose_to_line(obj.pose)}")
    lines.append("time: " + ", ".join(f"{k} {v:.3f} s" for k, v in result.seconds.items()))
    return "\n".join(lines)


def library_of(names: list[str] | None, known: KnownObjects) -> tuple[list[str], list[str], list[str]]:
    """(objects, distractors, own objects) of the library: ``names`` split by kind (``KnownObjects.get``;
    InputError for an unknown name), or without names every object, distractor and own object with artifacts."""
    if not names:
        library = (list(known.with_artifacts), list(known.distractors_with_artifacts), list(known.own_with_artifacts))
        if not any(library):
            raise InputError(f"no objects to identify among: {known.listing()}")
        return library
    found = [known.get(name) for name in names]  # InputError for an unknown name
    return tuple([o.name for o in found if o.kind == kind] for kind in ("object", "distractor", "own"))


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    cfg = compose_config(args.overrides)
    use_solver_devices(cfg)
    from tactile6d.estimation.identifier import Identifier  # torch, JAX: not loaded for --help
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    known = KnownObjects(artifacts, cfg)
    objects, distractors, own = library_of(args.objects, known)
    T_world_sensors, images = read_scene_dir(args.scene)
    offsets = read_sensor_offsets(args)
    if offsets is not None:
        from tactile6d.estimation.sensor_offsets import apply_sensor_offsets

        T_world_sensors = apply_sensor_offsets(T_world_sensors, offsets)
    background = one_scene_background_option(args.background, "identify")
    backgrounds, note = scene_backgrounds(Path(args.scene), len(T_world_sensors), background is not None)
    if note:
        print(note, file=sys.stderr)
    with Identifier.from_artifacts(objects, artifacts, cfg, background=background, distractors=distractors,
                                   own=own) as identifier:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", UnderdeterminedPoseWarning)
            warnings.simplefilter("always", LightWarning)
            result = identifier.identify(T_world_sensors, images, backgrounds)
    for line in dict.fromkeys(warnings_to_lines(Path(args.scene), caught)):  # each object's estimate may say it
        print(line, file=sys.stderr)
    print(json.dumps({"scene": str(args.scene), **result.to_dict()}) if args.json else as_text(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
