"""``tactile6d identify``: which object of a library touches the sensors, and its pose.

Scene folders in the paper's triplet layout (``poses_sensors.txt`` + ``Image_heatmap_<i>.png``, as for
``tactile6d estimate``: ``--scene DIR [DIR ...]`` or ``--scenes-root DIR``), each against the objects given with
``--objects`` (default: every object with artifacts in the artifacts directory, every distractor with artifacts
in its ``distractors/`` folder, ``identify.distractors``, and every one of your own objects with artifacts in
``own/``). The
images are read once; every object is estimated on them and scored with the weights the
``calibrate_identify`` stage fitted on the calibration scenes (``identify.calibration_scenes``;
``tactile6d.estimation.identifier``). Output: one line per object, most probable first, with its probability,
score and best pose (``x y z ax ay az angle``, world frame), objects that match nothing last; then the
time per step; several scenes each headed by ``# <folder>``. ``--json``: one JSON object per scene
(``Identification.to_dict``). The library's artifacts are loaded once for all the scenes of a call, which is
most of a single scene's time. Errors: one ``error:`` line and exit status 2; objects without artifacts are all
named in that one line; with several scenes a scene that fails prints its line (and with ``--json`` a line with
its ``error``), the others still print, and the exit status is 1. The sensors' no-contact images:
``--background`` (one file for every sensor, or one per sensor in sensor order; ``from-scenes`` estimates them
from the scenes' images), else the scene folder's ``background_<i>.png`` when it holds them (said on stderr),
else ``render.background``, an image that looks like another unit's against it read against the known unit's
it agrees with (``--known-units`` adds your own), as for ``tactile6d estimate``; one sensor only gives a
``warning:`` line.
``--sensor-offsets FILE`` corrects the sensor poses by the hand's offsets (``tactile6d calibrate-sensors``) first.
``--plot PATH`` draws the most probable object's estimate as ``tactile6d estimate --plot`` does (one scene: the
figure's file; several: a folder of ``<parent folder>_<scene folder>.png``); a scene that nothing matches gets none.

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
from tactile6d.cli.estimate import (FROM_SCENES, add_known_units_argument, add_sensor_offsets_argument,
                                    background_option, collect_scenes, error_json, error_line, is_override,
                                    known_units_option, object_mesh, plot_paths,
                                    read_scene_folder, read_sensor_offsets, split_overrides, use_solver_devices,
                                    warnings_to_lines, write_plot)
from tactile6d.cli.objects import KnownObjects
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError, InputError, Tactile6dError
from tactile6d.core.geometry import pose_to_line
from tactile6d.perception.inputs import UnderdeterminedPoseWarning
from tactile6d.perception.photometric import LightWarning

if TYPE_CHECKING:
    from tactile6d.estimation.identifier import Identification


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="tactile6d identify", description=description(__doc__),
        usage="tactile6d identify (--scene DIR [DIR ...] | --scenes-root DIR) [--objects NAME ...] [options] "
              "[key=value ...]")
    parser.add_argument("--scene", nargs="+", action="extend", default=[], metavar="DIR",
                        help="scene folder(s): poses_sensors.txt + Image_heatmap_<i>.png")
    parser.add_argument("--scenes-root", default=None, metavar="DIR",
                        help="every folder under DIR holding a poses_sensors.txt is a scene")
    parser.add_argument("--objects", nargs="+", default=None, metavar="NAME",
                        help="the candidate objects (default: every object with artifacts)")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--json", action="store_true", help="print one JSON object per scene")
    parser.add_argument("--background", nargs="+", default=None, metavar="PNG",
                        help="the sensors' own no-contact image(s) (PNG, 240 x 320): one for every sensor or one "
                             f"per sensor in sensor order; '{FROM_SCENES}': each sensor's estimated from its images "
                             "in the scenes given; default: the scene's background_<i>.png, else render.background")
    add_known_units_argument(parser)
    add_sensor_offsets_argument(parser, "poses_sensors.txt's poses")
    parser.add_argument("--plot", type=Path, default=None, metavar="PATH",
                        help="draw the most probable object's estimate (as tactile6d estimate --plot); one scene: the "
                             "figure's file; several: a folder of <parent>_<scene>.png")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    args = parser.parse_args(argv)
    moved = [word for word in args.scene if is_override(word)]  # ``--scene A B key=value``: nargs='+' is greedy
    args.scene = [word for word in args.scene if not is_override(word)]
    args.background, args.overrides = split_overrides(args.background, moved + list(args.overrides))
    args.known_units, args.overrides = split_overrides(args.known_units, args.overrides)
    if not args.scene and args.scenes_root is None:
        parser.error("give --scene DIR [DIR ...] or --scenes-root DIR")
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
    scenes = collect_scenes(args)
    offsets = read_sensor_offsets(args)
    background = background_option(args.background, scenes)
    known_units = known_units_option(args.known_units, args.background)
    plots = plot_paths(scenes, args.plot, single=len(scenes) == 1)
    failed = 0
    with Identifier.from_artifacts(objects, artifacts, cfg, background=background, distractors=distractors,
                                   own=own, known_units=known_units) as identifier:
        for k, scene in enumerate(scenes):
            try:
                result = identify_scene(identifier, scene, offsets, background is not None, plots.get(scene), known)
            except ConfigError:
                raise  # the same for every scene
            except Tactile6dError as exc:
                if len(scenes) == 1:
                    raise
                failed += 1
                print(error_line(scene, exc), file=sys.stderr)
                if args.json:
                    print(error_json(scene, exc))
                continue
            if args.json:
                print(json.dumps({"scene": str(scene), **result.to_dict()}))
            elif len(scenes) == 1:
                print(as_text(result))
            else:
                print(("\n" if k else "") + f"# {scene}\n" + as_text(result))
    if failed:
        print(f"error: {failed} of {len(scenes)} scenes failed", file=sys.stderr)
    return 1 if failed else 0


def identify_scene(identifier, scene: Path, offsets, background_given: bool, plot: Path | None = None,
                   known: KnownObjects | None = None) -> Identification:
    """One scene folder identified: its poses corrected by the hand's ``offsets`` (or None), its own no-contact
    images used unless ``--background`` was given; notes and warnings (each said once) on stderr; with ``plot``,
    the most probable object's estimate drawn there (``estimate.write_plot``; its mesh from ``known``'s artifacts
    when its estimator holds none)."""
    T_world_sensors, images, backgrounds, lines = read_scene_folder(scene, background_given)
    for line in lines:
        print(line, file=sys.stderr)
    if offsets is not None:
        from tactile6d.estimation.sensor_offsets import apply_sensor_offsets

        T_world_sensors = apply_sensor_offsets(T_world_sensors, offsets)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnderdeterminedPoseWarning)
        warnings.simplefilter("always", LightWarning)
        result = identifier.identify(T_world_sensors, images, backgrounds)
    for line in dict.fromkeys(warnings_to_lines(scene, caught)):  # each object's estimate may say it
        print(line, file=sys.stderr)
    best = result.best
    if plot is not None and best.pose is not None:
        estimator = identifier.full[best.name]
        write_plot(plot, f"{scene}: {best.name}, p {best.probability:.2f}", estimator.points,
                   object_mesh(estimator, known, best.name), T_world_sensors, images, best.candidate.estimate)
    elif plot is not None:
        print(f"note: {scene}: no object matches, so no figure", file=sys.stderr)
    return result


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
