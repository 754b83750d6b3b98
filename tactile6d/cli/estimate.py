"""``tactile6d estimate``: an object's pose from scene folders in the paper's triplet layout.

Each scene folder holds ``poses_sensors.txt`` (one ``x y z ax ay az angle`` line per sensor, world
frame) and ``Image_heatmap_<i>.png`` (sensor i's tactile image; ``.jpg`` or ``.jpeg`` where there is no PNG;
another size of its proportions is read resized, with a warning), and may hold ``background_<i>.png``
(sensor i's own no-contact image, for every sensor): the images are then read against those, as a note
on stderr says, unless ``--background`` is given (one file for every sensor, or one per sensor in sensor
order), which wins. With neither, the default (``render.background``) is used, and an image that looks like
another unit's against it is read against the known unit's it agrees with (``encode.KNOWN_UNITS``, and your
own units' given with ``--known-units``), as a ``warning:`` line says. ``--sensor-offsets FILE`` corrects the
sensor poses by each sensor's mounting offset (``tactile6d calibrate-sensors``) before anything reads them. One
sensor only is estimated with a ``warning:`` line on stderr (the pose is under-determined). Scenes are given with
``--scene DIR [DIR ...]`` and/or ``--scenes-root DIR`` (every folder under DIR that holds a
``poses_sensors.txt``, in natural order: ``triplet_2`` before ``triplet_10``). All scenes run in one
process; each object's artifacts are read once, from ``--artifacts`` (default: the config's
``paths.artifacts_dir``), without DVC.

The object: ``--object NAME`` for every scene, or ``--object auto``: each scene's object is the name
of the folder that holds the scene folder, as in the paper's layout
``caddeo2023/triplets/<object>/triplet_<k>``. An unknown name is an error listing the known ones: the
objects with artifacts in the artifacts directory, those of the configured object sets (``conf/objects``)
and the identification library's distractors (``identify.distractors``, their artifacts read from
``<artifacts>/distractors/``; ``tactile6d.cli.objects``). Missing artifacts are one error naming every
missing file and the ``dvc repro`` targets that make them.

Output, per scene: the best ``T_world_object`` as one ``x y z ax ay az angle`` line, then a short
summary (scores, confidence, selection, time per step); with several scenes each result is headed by a
``# <scene folder> (<object>)`` line. The confidence is the calibrated probability that the best pose
is within 1 cm ADI of the truth (stage calibrate_confidence; without its model in the artifacts, a
note says there is none); when other ranked poses, far from the best, explain the contacts about
equally well, an ``ambiguous:`` line gives their ranks (0 the best): the best may then be the wrong one.
With ``--json``: one JSON object per line (JSON Lines) with the scene folder, the object, the top-K
poses as 4x4 matrices, their scores, losses and penetrations, the selection diagnostics, the timings,
``confidence`` (null without a model), ``ambiguous`` and ``distinct_poses`` (rank, pose and score of
each pose that explains the contacts about equally well, the best first; empty without a model) and
``load_seconds`` (the time spent loading the object's artifacts for that scene, 0 once they are
loaded). With ``--suggest-touch``, an ambiguous estimate also says where one more touch would tell its poses
apart (``disambiguation.touch_to_tell_apart``: a ``touch:`` line; in JSON ``touch``, null when the estimate is
not ambiguous, else its ``point`` and ``normal`` (world; approach along minus the normal), the
``T_world_sensor`` pressing there if the best pose is right, the ``separation`` (m) from the rivals'
surfaces and ``tells_apart``, false where no reachable flat spot lies 3 mm from them and the touch is the
flattest spot's, which pins the pose better without telling the poses apart); after the touch,
``disambiguation.choose`` re-ranks the poses. A progress bar goes to stderr when there are more than a few
scenes and stderr is a terminal.

``--plot PATH`` draws each estimate (``tactile6d.evaluation.estimate_figure``): the object at the best pose among
the sensors, and per sensor its image with the press read from it (white outline) and the press the best pose
makes (orange), with their depths and mask IoU side by side. With one ``--scene``, PATH is the figure's file (its
suffix picks the format: PNG, PDF, SVG, JPG); with several scenes, a folder that gets one PNG per scene named
``<parent folder>_<scene folder>.png`` (``004_sugar_box_triplet_0.png`` in the paper's layout).

Errors: with one ``--scene``, any error ends the command with one ``error:`` line and exit status 2,
as for a bad option, an unknown object or a bad config override in every case. With several scenes,
a scene that fails (unreadable folder, bad pose line, no matching tuple, missing artifacts of its
object) prints one ``error: <scene folder>: ...`` line on stderr, the others still print, and the
exit status is 1.

Config overrides (Hydra syntax, ``key=value``) pass through anywhere on the line, e.g.
``select.method=baseline select.delta_h=0.05 select.N=2000``, or ``preset=paper`` for the paper's
method end to end.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tactile6d.cli import description
from tactile6d.cli.objects import KnownObjects
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError, DataError, InputError, NoMatch, Tactile6dError
from tactile6d.core.geometry import pose_to_line
from tactile6d.data.hdf5 import (
    ImageSizeWarning,
    read_background_images,
    read_scene_backgrounds,
    read_scene_dir,
    read_tactile_image,
)
from tactile6d.perception import photometric
from tactile6d.perception.inputs import PenetrationWarning, UnderdeterminedPoseWarning

if TYPE_CHECKING:
    from tactile6d.estimation.estimator import Estimate, Estimator
    from tactile6d.estimation.sensor_offsets import SensorOffsets

# The estimator's modules (torch, JAX, trimesh: seconds to import) are imported where a command uses them, so
# that `--help` and a bad option answer at once (tests/test_cli_imports.py).

AUTO = "auto"
# Below this many scenes a progress bar is more noise than help.
PROGRESS_MIN_SCENES = 4
# A Hydra override: key=value, +key=value, ++key=value, ~key[=value], group@package=option. Paths
# have a '/' before any '=', so a scene folder is never taken for one.
_OVERRIDE = re.compile(r"^(\+\+|\+|~)?[A-Za-z_][\w.]*(@[\w.]*)?(=|$)")


def parse_args(argv: list[str]) -> argparse.Namespace:
    """Options, with the ``key=value`` words that landed among ``--scene``'s folders moved to overrides."""
    parser = argparse.ArgumentParser(
        prog="tactile6d estimate",
        description=description(__doc__),
        usage=("tactile6d estimate --object NAME|auto --scene DIR [DIR ...] [options] [key=value ...]\n"
               "       tactile6d estimate --object NAME|auto --scenes-root DIR [options] [key=value ...]"),
    )
    add_scene_arguments(parser, "scene", "poses_sensors.txt + Image_heatmap_<i>.png")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--top", type=int, default=None, help="poses to report (sets rank.top_k; default 5)")
    parser.add_argument("--json", action="store_true", help="print one JSON object per scene (JSON Lines)")
    parser.add_argument("--background", nargs="+", default=None, metavar="PNG",
                        help="the sensors' own no-contact image(s) (PNG, 240 x 320): one for every sensor or one "
                             "per sensor in sensor order; 'from-scenes': each sensor's estimated from its images "
                             f"in the scenes given (pixel median; at least {MIN_SCENES_FOR_BACKGROUND} scenes "
                             "that touch in different places); default: each scene's background_<i>.png, else "
                             "render.background")
    add_known_units_argument(parser)
    add_sensor_offsets_argument(parser, "poses_sensors.txt's poses")
    parser.add_argument("--suggest-touch", action="store_true",
                        help="when the estimate is ambiguous, also say where one more touch would tell its poses "
                             "apart (docs/confidence.md)")
    parser.add_argument("--plot", type=Path, default=None, metavar="PATH",
                        help="draw each estimate: the object among the sensors and each gel's press read against "
                             "the best pose's; one scene: the figure's file (PNG, PDF, SVG or JPG); several: a "
                             "folder of <parent>_<scene>.png")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    args = parser.parse_args(argv)
    # ``--scene A B select.N=5`` puts the override among the folders (nargs='+' is greedy).
    moved = [word for word in args.scene if is_override(word)]
    args.scene = [word for word in args.scene if not is_override(word)]
    args.background, args.overrides = split_overrides(args.background, moved + list(args.overrides))
    args.known_units, args.overrides = split_overrides(args.known_units, args.overrides)
    if not args.scene and args.scenes_root is None:
        parser.error("give --scene DIR [DIR ...] or --scenes-root DIR")
    return args


def add_scene_arguments(parser: argparse.ArgumentParser, what: str, holds: str) -> None:
    """``--object NAME|auto``, ``--scene DIR [DIR ...]`` and ``--scenes-root DIR``, for commands that read scene
    folders (``what`` each is called in the help, ``holds`` what a folder holds)."""
    parser.add_argument("--object", required=True, metavar="NAME|auto",
                        help=f"object name for every {what}, or 'auto': each {what}'s parent folder names it")
    parser.add_argument("--scene", nargs="+", action="extend", default=[], metavar="DIR",
                        help=f"{what} folder(s): {holds}")
    parser.add_argument("--scenes-root", default=None, metavar="DIR",
                        help=f"every folder under DIR holding a poses_sensors.txt is a {what}")


def add_sensor_offsets_argument(parser: argparse.ArgumentParser, poses: str) -> None:
    """``--sensor-offsets FILE``: the hand's offsets from ``tactile6d calibrate-sensors``, applied to ``poses``."""
    parser.add_argument("--sensor-offsets", default=None, metavar="FILE",
                        help=f"each sensor's mounting offset, applied to {poses} before anything else (JSON from "
                             "`tactile6d calibrate-sensors`)")


def add_known_units_argument(parser: argparse.ArgumentParser) -> None:
    """``--known-units PATH [PATH ...]``: the user's own DIGIT units' no-contact images (``known_units_option``)."""
    parser.add_argument("--known-units", nargs="+", default=None, metavar="PATH",
                        help="your DIGIT units' no-contact images (PNG or JPEG, 240 x 320 or another size of its "
                             "proportions, read resized), files or folders of "
                             "them, each unit named by its file's stem: an image passed without its own no-contact "
                             "image that does not agree with the default is read against the unit's it agrees "
                             "with, among these and the data directory's (not with --background)")


def use_solver_devices(cfg) -> None:
    """The solver's CPU devices set up (``optimize.use_cpu_devices_for``), before anything imports JAX's
    computations; imported here, not at the top, since JAX takes seconds to load."""
    from tactile6d.estimation.optimize import use_cpu_devices_for

    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))


def read_sensor_offsets(args: argparse.Namespace) -> SensorOffsets | None:
    """``--sensor-offsets``' file read, or None when not given."""
    if not args.sensor_offsets:
        return None
    from tactile6d.estimation.sensor_offsets import SensorOffsets

    return SensorOffsets.read(args.sensor_offsets)


def split_overrides(words: list[str] | None, overrides: list[str]) -> tuple[list[str] | None, list[str]]:
    """(the words of a greedy list option, e.g. ``--background``'s files, without the overrides that landed
    among them; ``overrides`` with those moved in front)."""
    if words is None:
        return None, overrides
    return [w for w in words if not is_override(w)], [w for w in words if is_override(w)] + overrides


def is_override(word: str) -> bool:
    """Whether a command-line word is a config override rather than a scene folder."""
    # ``~key`` (delete a key) is the one override form without '='.
    looks_like_one = bool(_OVERRIDE.match(word)) and ("=" in word or word.startswith("~"))
    return looks_like_one and not Path(word).exists()


def natural_key(path: Path) -> list:
    """Sort key that orders the numbers in a path by value (``triplet_2`` before ``triplet_10``)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.as_posix())]


def find_scenes(root: str | Path) -> list[Path]:
    """Every folder under ``root`` (itself included) that holds a ``poses_sensors.txt``, naturally sorted."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"scenes root {root} not found")
    scenes = sorted({p.parent for p in root.rglob("poses_sensors.txt")}, key=natural_key)
    if not scenes:
        raise InputError(f"no scene folder (one holding poses_sensors.txt) under {root}")
    return scenes


def collect_scenes(args: argparse.Namespace) -> list[Path]:
    """The ``--scene`` folders, then those found under ``--scenes-root``, each once."""
    scenes = [Path(s) for s in args.scene]
    if args.scenes_root is not None:
        scenes += find_scenes(args.scenes_root)
    return list(dict.fromkeys(scenes))


def object_of(scene: Path, object_arg: str, known: KnownObjects) -> str:
    """The object of one scene: ``--object``'s name, or with ``auto`` the scene's parent folder's name."""
    if object_arg != AUTO:
        return object_arg
    name = scene.resolve().parent.name
    if name not in known:
        raise InputError(f"--object auto takes the object from the folder holding the scene, and {name!r} "
                         f"is not a known object; {known.listing()}")
    return name


class EstimatorCache:
    """One Estimator per object, loaded on first use; a load that failed fails again without retrying.
    ``offsets``: the hand's sensor offsets (``tactile6d calibrate-sensors``), which ``sensor_poses`` applies;
    ``known_units``: the user's units' no-contact images (``known_units_option``)."""

    def __init__(self, known: KnownObjects, cfg, background: np.ndarray | None, offsets: SensorOffsets | None = None,
                 known_units: dict[str, np.ndarray] | None = None):
        self.known, self.cfg, self.background, self.offsets = known, cfg, background, offsets
        self.known_units = known_units
        self._loaded: dict[str, tuple[Estimator | Tactile6dError, float]] = {}
        self._reported: set[str] = set()

    def load(self, name: str) -> Estimator:
        """The object's Estimator, loading it if not yet done; the Tactile6dError of a failed load."""
        if name not in self._loaded:
            from tactile6d.estimation.estimator import Estimator

            t0 = time.perf_counter()
            try:
                found = self.known.require_artifacts(name, baseline=self.cfg.select.method != "ours")
                loaded = Estimator.from_artifacts(name, self.known.artifacts, self.cfg, background=self.background,
                                                  objects_dir=found.objects_dir, known_units=self.known_units)
            except ConfigError:
                raise  # the same for every object: not worth remembering
            except Tactile6dError as exc:
                loaded = exc
            self._loaded[name] = (loaded, time.perf_counter() - t0)
        loaded = self._loaded[name][0]
        if isinstance(loaded, Tactile6dError):
            raise loaded
        return loaded

    def sensor_poses(self, T_world_sensors: np.ndarray) -> np.ndarray:
        """The sensor poses as read, corrected by the hand's offsets when there are any."""
        if self.offsets is None:
            return T_world_sensors
        from tactile6d.estimation.sensor_offsets import apply_sensor_offsets

        return apply_sensor_offsets(T_world_sensors, self.offsets)

    def get(self, name: str) -> tuple[Estimator, float]:
        """The object's Estimator and the seconds its loading took, counted once: 0.0 on later calls."""
        estimator, seconds = self.load(name), self._loaded[name][1]
        first = name not in self._reported
        self._reported.add(name)
        return estimator, seconds if first else 0.0


def summary(result: Estimate, cfg) -> list[str]:
    """A few human-readable lines: method, scores, confidence, selection diagnostics, time per step."""
    sel = result.selection
    lines = [
        (
            f"method {cfg.select.method}, solver {cfg.optimize.solver}: {len(result.poses)} distinct poses "
            f"of {result.n_hypotheses} hypotheses"
        ),
        (
            # The score is loss + deepest penetration only in the paper's method; by default it also counts
            # render-and-compare and the sensor corrections, and forgives the sensors' expected error.
            f"best: score {1000 * result.scores[0]:.2f} mm; loss {1000 * result.losses[0]:.2f} mm, "
            f"deepest penetration {1000 * result.penetrations[0].max():.2f} mm"
        ),
        *confidence_lines(result),
    ]
    omegas = ", ".join(str(n) for n in sel.omega_sizes)
    if cfg.select.method == "ours":
        widened = [f"sensor {i} widened to {sel.delta_h[i]:.3g} rad" for i in np.flatnonzero(sel.widened)]
        angles = ", ".join(f"{a:.3f}" for a in result.angles)
        lines.append(f"latent angles {angles} rad; |Omega_i| {omegas} at delta_h {cfg.select.delta_h:g} rad"
                     + (f" ({'; '.join(widened)})" if widened else ""))
    else:
        lines.append(f"baseline: |Omega_i| {omegas} (every database point)")
    lines.append(f"{sel.tuples.shape[0]} tuples at delta_d {1000 * sel.delta_d:.2f} mm"
                 + (" (capped at N)" if sel.capped else ""))
    steps = ", ".join(f"{k} {v:.3f} s" for k, v in result.seconds.items())
    lines.append(f"time: {steps}")
    return lines


def confidence_lines(result: Estimate) -> list[str]:
    """The confidence line and, when other poses explain the contacts about equally well, one that says so;
    one note when the artifacts hold no confidence model."""
    from tactile6d.estimation import confidence

    within = f"{100 * confidence.SUCCESS_ADI:g} cm ADI"
    if result.confidence is None:
        return ["confidence: none (no confidence model; `dvc repro calibrate_confidence` makes it)"]
    lines = [f"confidence {result.confidence:.2f} (P that the best pose is within {within})"]
    if result.ambiguous:
        ranks = ", ".join(str(i) for i in result.distinct)
        lines.append(f"ambiguous: {len(result.distinct)} distinct poses (ranks {ranks}; 0 the best) explain "
                     "the contacts about equally well: the best may be the wrong one")
    return lines


def estimate_scene(scene: Path, name: str, cache: EstimatorCache, suggest_touch: bool = False,
                   plot: Path | None = None):
    """One scene's estimate, the seconds spent loading its object's artifacts for it and, with ``suggest_touch``
    and an ambiguous estimate, where one more touch would tell its poses apart (``Touch``; else None); its notes
    and warnings (``scene_backgrounds``, ``warnings_to_lines``) go to stderr; with ``plot``, its figure is
    written there (``write_plot``)."""
    T_world_sensors, images, backgrounds, lines = read_scene_folder(scene, cache.background is not None)
    for line in lines:
        write(line, sys.stderr)
    estimator, load_seconds = cache.get(name)
    from tactile6d.perception.contacts import UntouchedSensorWarning  # OpenCV and trimesh: not for --help

    with warnings.catch_warnings(record=True) as caught:
        # What an estimate may warn about its scene, printed for every scene it concerns, not once per batch.
        for kind in (UnderdeterminedPoseWarning, photometric.LightWarning, UntouchedSensorWarning, PenetrationWarning):
            warnings.simplefilter("always", kind)
        T = cache.sensor_poses(T_world_sensors)
        result = estimator.estimate(T, images, backgrounds)
    for line in warnings_to_lines(scene, caught):
        write(line, sys.stderr)
    touch = None
    if suggest_touch and result.ambiguous:
        from tactile6d.estimation.disambiguation import touch_to_tell_apart

        touch = touch_to_tell_apart(estimator.surface, result.poses[result.distinct], T)
    if plot is not None:
        write_plot(plot, f"{scene} ({name})", estimator.points, object_mesh(estimator, cache.known, name), T, images,
                   result)
    return result, load_seconds, touch


def object_mesh(estimator: Estimator, known: KnownObjects, name: str):
    """The object's mesh (``--plot`` draws its presses): the estimator's own when it renders and compares, else
    read from the object's artifacts (``object_artifacts.load_mesh``, whose file reads are cached)."""
    if estimator.mesh is not None:
        return estimator.mesh
    from tactile6d.data.object_artifacts import load_mesh

    return load_mesh(known.get(name).objects_dir, name)


def write_plot(path: Path, title: str, points: np.ndarray, mesh, T_world_sensors: np.ndarray, images: np.ndarray,
               result: Estimate) -> None:
    """The estimate's figure (``estimate_figure.estimate_figure``; points (N, 3) on the object, its frame) written
    to ``path``, titled with ``title`` and the confidence; DataError when it cannot be written."""
    import matplotlib.pyplot as plt

    from tactile6d.evaluation.estimate_figure import estimate_figure

    if result.confidence is not None:
        title += f": confidence {result.confidence:.2f}" + (", ambiguous" if result.ambiguous else "")
    fig = estimate_figure(points, mesh, T_world_sensors, images, result, title)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=80)
    except OSError as exc:
        raise DataError(f"cannot write the figure {path}: {exc}") from exc
    finally:
        plt.close(fig)


def plot_paths(scenes: list[Path], plot: Path | None, single: bool) -> dict[Path, Path]:
    """Where ``--plot`` puts each scene's figure: ``plot`` itself for a ``single`` scene, else ``plot`` taken for a
    folder holding ``<parent folder>_<scene folder>.png`` per scene (a number added where two scenes share the
    name); {} without ``--plot``. InputError when ``plot`` is a folder for one scene or a file for several."""
    if plot is None:
        return {}
    if single:
        if plot.is_dir():
            raise InputError(f"--plot {plot} is a folder; with one scene it is the figure's file, e.g. "
                             f"{plot}/estimate.png")
        from matplotlib.backend_bases import FigureCanvasBase

        if plot.suffix.lower().lstrip(".") not in FigureCanvasBase.get_supported_filetypes():
            raise InputError(f"--plot {plot}: no figure is written as {plot.suffix or 'a file without a suffix'}; "
                             "name it .png, .pdf, .svg or .jpg")
        return {scenes[0]: plot}
    if plot.exists() and not plot.is_dir():
        raise InputError(f"--plot {plot} is a file; with several scenes it is the folder that gets one figure per "
                         "scene")
    paths: dict[Path, Path] = {}
    for scene in scenes:
        folder = scene.resolve()
        stem = f"{folder.parent.name}_{folder.name}"
        path, k = plot / f"{stem}.png", 2
        while path in paths.values():
            path, k = plot / f"{stem}_{k}.png", k + 1
        paths[scene] = path
    return paths


def touch_line(touch) -> str:
    """The ``touch:`` line of an ambiguous estimate (``--suggest-touch``)."""
    if touch is None:
        return "touch: none reachable that tells the poses apart"
    point = " ".join(f"{v:.4f}" for v in touch.point)
    normal = " ".join(f"{v:.3f}" for v in touch.normal)
    where = (f"touch: one more sensor at {point} (m), moved in along minus the normal {normal} until it meets the "
             "object, ")
    apart = f"their surfaces {100 * touch.separation:.1f} cm apart there"
    if touch.tells_apart:
        return f"{where}tells the poses apart ({apart}); then disambiguation.choose"
    # The fallback: no reachable flat spot where the poses' surfaces part; the touch still pins the pose better.
    return (f"{where}pins the pose better but barely tells the poses apart ({apart}: no reachable flat spot where "
            "they part more); then disambiguation.choose")


def touch_json(touch) -> dict | None:
    """``--suggest-touch``'s JSON: the touch's point, normal, sensor pose, separation and whether it tells the poses
    apart (``Touch.tells_apart``), or None."""
    if touch is None:
        return None
    return {"point": touch.point.tolist(), "normal": touch.normal.tolist(),
            "T_world_sensor": touch.T_world_sensor.tolist(), "separation": touch.separation,
            "tells_apart": touch.tells_apart}


FROM_SCENES = "from-scenes"  # --background's word for "estimate each sensor's from the scenes' images"
MIN_SCENES_FOR_BACKGROUND = 5


def backgrounds_from_scenes(scenes: list[Path]) -> tuple[np.ndarray, str]:
    """Each sensor's no-contact image (L, 320, 240, 3) estimated from its images in ``scenes``
    (``photometric.background_from_images``: the pixel median), for units whose own was never recorded,
    and a note for stderr that says so. InputError for fewer than ``MIN_SCENES_FOR_BACKGROUND`` scenes or
    scenes with different sensor counts."""
    images = [read_scene_dir(scene)[1] for scene in scenes]
    counts = sorted({len(i) for i in images})
    if len(counts) > 1:
        raise InputError(f"--background {FROM_SCENES}: the scenes have different sensor counts {counts}; each "
                         "sensor's no-contact image is estimated from the same sensor in every scene")
    per_sensor = [photometric.background_from_images(np.stack([i[k] for i in images]), MIN_SCENES_FOR_BACKGROUND)
                  for k in range(counts[0])]
    if per_sensor[0] is None:
        raise InputError(f"--background {FROM_SCENES} needs at least {MIN_SCENES_FOR_BACKGROUND} scenes, touching in "
                         f"different places, to estimate the no-contact images; got {len(scenes)}")
    return np.stack(per_sensor), (f"note: each sensor's no-contact image estimated from its images in the "
                                  f"{len(scenes)} scenes (pixel median): record them with nothing touching the "
                                  "sensors for better readings")


def background_option(words: list[str] | None, scenes: list[Path]) -> np.ndarray | None:
    """``--background``'s no-contact images: read from its files, estimated from the scenes' images with
    ``from-scenes`` (a note on stderr says so), or None when not given."""
    if words == [FROM_SCENES]:
        background, note = backgrounds_from_scenes(scenes)
        write(note, sys.stderr)
        return background
    return read_background_images(words) if words else None


UNIT_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def known_units_option(paths: list[str] | None, background: list[str] | None) -> dict[str, np.ndarray] | None:
    """``--known-units``' no-contact images, name (the file's stem) -> (320, 240, 3) uint8 RGB, from files and
    folders (every PNG or JPEG in one), or None when not given. InputError beside ``--background`` (with which
    they would never be looked at), for a path that is neither, a folder without images and two files of one
    name."""
    if not paths:
        return None
    if background:
        raise InputError("--known-units are looked at only for images read without their own no-contact image: "
                         "give --background or --known-units, not both")
    files = []
    for path in map(Path, paths):
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in UNIT_IMAGE_SUFFIXES and p.is_file())
            if not found:
                raise InputError(f"--known-units: {path} holds no PNG or JPEG image")
            files += found
        elif path.is_file():
            files.append(path)
        else:
            raise InputError(f"--known-units: {path} not found")
    named: dict[str, Path] = {}
    for file in files:
        if file.stem in named and named[file.stem] != file:
            raise InputError(f"--known-units: {named[file.stem]} and {file} both name unit {file.stem!r}; a unit is "
                             "named by its file's stem")
        named[file.stem] = file
    units = {}
    for name, file in named.items():
        try:
            units[name] = read_tactile_image(file)
        except InputError as exc:
            raise InputError(f"--known-units: {exc}") from exc
    return units


def one_scene_background_option(words: list[str] | None, command: str) -> np.ndarray | None:
    """``--background``'s files for a command that reads one scene (``command``: its name); ``from-scenes``, which
    needs the images of many, is an InputError that says where it works."""
    if words == [FROM_SCENES]:
        raise InputError(f"--background {FROM_SCENES} estimates the no-contact images from the images of several "
                         f"scenes, which `tactile6d estimate` and `tactile6d identify` read in one call; `tactile6d "
                         f"{command}` reads one scene: pass the sensors' no-contact image files")
    return read_background_images(words) if words else None


def scene_backgrounds(scene: Path, n_sensors: int, given: bool) -> tuple[np.ndarray | None, str | None]:
    """The scene folder's own no-contact images (``hdf5.read_scene_backgrounds``; None when it has none, or
    when ``--background`` was ``given``, which wins) and a note for stderr saying which are used."""
    backgrounds = read_scene_backgrounds(scene, n_sensors)
    if backgrounds is None:
        return None, None
    if given:
        return None, f"note: {scene}: --background given, the folder's background_<i>.png are not used"
    return backgrounds, (f"note: {scene}: each sensor's image is read against its own no-contact image "
                         f"background_<i>.png (i = 0..{n_sensors - 1})")


def read_scene_folder(scene: Path, background_given: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[str]]:
    """A scene folder read (``read_scene_dir``, and its own no-contact images unless ``--background`` was
    ``background_given``: ``scene_backgrounds``) -> T_world_sensors (L, 4, 4), images (L, 320, 240, 3), its
    no-contact images or None, and the lines for stderr: the note on its no-contact images and, for images of
    another size read resized, one warning line per size (``warnings_to_lines``)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ImageSizeWarning)
        T_world_sensors, images = read_scene_dir(scene)
        backgrounds, note = scene_backgrounds(scene, len(T_world_sensors), background_given)
    return T_world_sensors, images, backgrounds, ([note] if note else []) + warnings_to_lines(scene, caught)


def warnings_to_lines(scene: Path, caught: list) -> list[str]:
    """Caught warnings -> one ``warning: <scene>: <message>`` line each (the CLI's form of the API's warnings), but
    one line for all the images of one size read resized (``hdf5.ImageSizeWarning``), naming their files."""
    sized: dict[str, list[str]] = {}
    lines = []
    for w in caught:
        if isinstance(w.message, ImageSizeWarning):
            name = Path(w.message.name)
            sized.setdefault(w.message.size_text(), []).append(name.name if name.parent == scene else str(name))
        else:
            lines.append(f"warning: {scene}: {' '.join(str(w.message).split())}")
    return [f"warning: {scene}: {', '.join(names)} {'is' if len(names) == 1 else 'are'} {text}"
            for text, names in sized.items()] + lines


def as_json(scene: Path, name: str, result: Estimate, cfg, load_seconds: float, suggest_touch: bool = False,
            touch=None) -> str:
    """One scene's result as one line of JSON; with ``suggest_touch``, its ``touch`` (``touch_json``)."""
    out = {"object": name, "scene": str(scene), "method": cfg.select.method, "solver": cfg.optimize.solver,
           "best": pose_to_line(result.best), **result.to_dict(), "load_seconds": load_seconds}
    if suggest_touch:
        out["touch"] = touch_json(touch)
    return json.dumps(out)


def as_text(scene: Path, name: str, result: Estimate, cfg, load_seconds: float, header: bool,
            suggest_touch: bool = False, touch=None) -> str:
    """One scene's result as text: the best pose line first (after the header, when there is one); with
    ``suggest_touch`` and an ambiguous estimate, its ``touch:`` line."""
    lines = [f"# {scene} ({name})"] if header else []
    lines += [pose_to_line(result.best), *summary(result, cfg)]
    if suggest_touch and result.ambiguous:
        lines.append(touch_line(touch))
    if not header:
        lines.append(f"(loading the artifacts took {load_seconds:.2f} s)")
    elif load_seconds > 0:
        lines.append(f"(loading the artifacts of {name} took {load_seconds:.2f} s)")
    return "\n".join(lines)


def error_line(scene: Path, exc: Tactile6dError) -> str:
    """``error: <scene>: <message>`` on one line; the folder is not repeated when the message names it."""
    message = " ".join(str(exc).split())
    return f"error: {message}" if str(scene) in message else f"error: {scene}: {message}"


def error_json(scene: Path, exc: Tactile6dError) -> str:
    """A failed scene's line of JSON output: ``{"scene": ..., "error": ...}``, so that a reader of the lines can
    line the results up with the scenes."""
    return json.dumps({"scene": str(scene), "error": " ".join(str(exc).split())})


def write(text: str, stream) -> None:
    """Print past the progress bar (tqdm clears and redraws it) and flush, so that a reader of a pipe
    gets each result as soon as it is ready."""
    from tqdm import tqdm

    tqdm.write(text, file=stream)
    stream.flush()


def run_batch(scenes: list[Path], args: argparse.Namespace, cfg, cache: EstimatorCache,
              known: KnownObjects) -> int:
    """Every scene in turn; a failed scene's error goes to stderr and makes the exit status 1."""
    plots = plot_paths(scenes, args.plot, single=False)
    from tqdm import tqdm

    show_bar = not args.no_progress and len(scenes) >= PROGRESS_MIN_SCENES
    failed = printed = 0
    # disable=None: tqdm draws the bar only when stderr is a terminal, so logs stay free of it.
    with tqdm(total=len(scenes), file=sys.stderr, unit="scene", desc="estimate",
              disable=None if show_bar else True, leave=False) as bar:
        for scene in scenes:
            try:
                name = object_of(scene, args.object, known)
                result, load_seconds, touch = estimate_scene(scene, name, cache, args.suggest_touch,
                                                             plots.get(scene))
            except ConfigError:
                raise  # a bad setting fails every scene alike: stop with exit status 2
            except Tactile6dError as exc:
                failed += 1
                write(error_line(scene, exc), sys.stderr)
                if args.json:
                    write(error_json(scene, exc), sys.stdout)
            else:
                if args.json:
                    write(as_json(scene, name, result, cfg, load_seconds, args.suggest_touch, touch), sys.stdout)
                else:
                    # a blank line between results
                    write(("\n" if printed else "") + as_text(scene, name, result, cfg, load_seconds, True,
                                                               args.suggest_touch, touch), sys.stdout)
                printed += 1
            bar.update(1)
    if failed:
        write(f"error: {failed} of {len(scenes)} scenes failed", sys.stderr)
    return 1 if failed else 0


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    overrides = list(args.overrides) + ([f"rank.top_k={args.top}"] if args.top is not None else [])
    cfg = compose_config(overrides)
    use_solver_devices(cfg)
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    known = KnownObjects(artifacts, cfg)
    if args.object != AUTO:
        known.get(args.object)  # an unknown name ends the command before any scene is read
    scenes = collect_scenes(args)
    cache = EstimatorCache(known, cfg, background_option(args.background, scenes), read_sensor_offsets(args),
                           known_units_option(args.known_units, args.background))

    if len(scenes) == 1 and args.scenes_root is None:
        # One scene, as before batches existed: no header, and any error ends the command (exit 2).
        scene = scenes[0]
        name = object_of(scene, args.object, known)
        plot = plot_paths(scenes, args.plot, single=True).get(scene)
        try:
            result, load_seconds, touch = estimate_scene(scene, name, cache, args.suggest_touch, plot)
        except (InputError, NoMatch) as exc:  # what is wrong with this scene: say which scene it is
            raise type(exc)(error_line(scene, exc).removeprefix("error: ")) from exc
        write(as_json(scene, name, result, cfg, load_seconds, args.suggest_touch, touch) if args.json
              else as_text(scene, name, result, cfg, load_seconds, False, args.suggest_touch, touch), sys.stdout)
        return 0
    if args.object != AUTO:
        # One object for all: missing artifacts would fail every scene, so they end the command here.
        cache.load(args.object)
    return run_batch(scenes, args, cfg, cache, known)
