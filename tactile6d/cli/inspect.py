"""``tactile6d inspect``: what the estimator reads from one scene's images, sensor by sensor, without estimating.

For checking a set-up (real sensors, a hand's poses, recorded no-contact images) before trusting its
estimates, and for finding out why an estimate went wrong. The scene folder is in the layout of
``tactile6d estimate`` (``poses_sensors.txt``, ``Image_heatmap_<i>.png``, optionally ``background_<i>.png``)
and the no-contact images are chosen as it chooses them (``--background``, else the folder's
``background_<i>.png``, else ``render.background``, against which an image that looks like another unit's is read
against the known unit's it agrees with: ``encode.KNOWN_UNITS`` and yours, ``--known-units``). The reading steps
of ``Estimator.estimate`` then run on it (``read_scene``): the light alignment (``perception.encode.align_light``)
and the contact patch of each image as aligned (``perception.contact_patch.image_to_patch``), which needs only the
patch calibration of ``--artifacts`` (stage calibrate_patch), no object. Printed per sensor:

- the contact: where on the gel (the pixel, and mm from the gel's centre), how deep the
  object presses, over how much of the image, how far the surface there is tilted from the camera's axis;
  or no contact, with the image's noise level;
- the light: gain and gamma per channel against its no-contact image, whether applied, and why not;
- each problem for which ``tactile6d estimate`` refuses the scene: a grey image, an image whose red and
  blue look swapped against its no-contact image, an image too saturated to read, and (for the scene)
  sensors whose bodies overlap. ``estimate`` stops at the first; this lists them all.

``--out FILE`` (PNG or JPG) writes a figure, one row per sensor: the image as given, its no-contact image, the difference
the reading sees (after the light alignment), and the press depth read from it with the patch's outline and
contact point. ``--json`` prints one JSON object instead of the text.

Exit status: 0 when the estimator would read the scene, 1 when it would refuse it (the problems are
listed), 2 for an error that stops the reading itself (a missing folder or file, a malformed pose, a bad
option or missing artifacts).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tactile6d.cli import description
from tactile6d.cli.estimate import (add_known_units_argument, known_units_option, one_scene_background_option,
                                    scene_backgrounds, split_overrides)
from tactile6d.core import sensor
from tactile6d.core.config import compose_config
from tactile6d.core.errors import DataError, InputError
from tactile6d.core.settings import SelectSettings, SensorSettings
from tactile6d.data.hdf5 import read_scene_dir
from tactile6d.perception import inputs, photometric

if TYPE_CHECKING:
    from tactile6d.perception.contact_patch import ContactPatch, PatchModel
    from tactile6d.perception.encode import KnownUnits

# perception.encode and contact_patch (torch, trimesh: seconds to load) are imported where they are used, so that
# --help answers at once.


@dataclass(frozen=True)
class SensorReading:
    """What one sensor's image says, as the estimator reads it.

    image, background (320, 240, 3) uint8 RGB: the image as given and its no-contact image; aligned: the
    image after the light alignment (what every later reading sees); light: its ``photometric.LightFit``
    (None when the light is not aligned, ``select.align_light`` off); patch: its ``ContactPatch`` (None when
    it cannot be read); problems: why the estimator would refuse it, each a sentence naming the image;
    unit: why its no-contact image looks like another unit's (``photometric.unit_problems``), or None;
    known_unit: the known unit whose no-contact image it is read against, its default's having looked like
    another unit's (``photometric.known_units_agreeing``), or None.
    """

    image: np.ndarray
    background: np.ndarray
    aligned: np.ndarray
    light: photometric.LightFit | None
    patch: ContactPatch | None
    problems: list[str]
    unit: str | None = None
    known_unit: str | None = None

    @property
    def light_problems(self) -> list[str]:
        """Why its light's reading cannot be trusted, as the estimator warns (``photometric.warn_about_light``):
        its no-contact image's unit, else the fit's problems."""
        if self.unit is not None:
            return [self.unit]
        return [] if self.light is None else self.light.problems()

    def to_dict(self) -> dict:
        """Plain numbers for JSON: the contact (``contact_summary``), the light's fit and the problems."""
        light = None
        if self.light is not None:
            # As ``light_problems`` says it: a grey or BGR image is not also taken for another unit's.
            light = {**self.light.to_dict(), "another_unit": self.unit is not None}
        return {**contact_summary(self.patch), "light": light, "light_problems": self.light_problems,
                "problems": self.problems, "known_unit": self.known_unit}


@dataclass(frozen=True)
class SceneReading:
    """Every sensor's ``SensorReading`` and the scene's own problems (sensors whose bodies overlap)."""

    sensors: list[SensorReading]
    problems: list[str]

    @property
    def refused(self) -> bool:
        """Whether ``Estimator.estimate`` would refuse the scene (an ``InputError``)."""
        return bool(self.problems) or any(s.problems for s in self.sensors)


def read_scene(T_world_sensors, images, backgrounds, model: PatchModel, select: SelectSettings,
               sensors: SensorSettings, known_units: KnownUnits | Mapping[str, np.ndarray] | None = None
               ) -> SceneReading:
    """The reading steps of ``Estimator.estimate`` on one scene, every problem collected.

    T_world_sensors (L, 4, 4); images (L, 320, 240, 3) uint8 RGB; backgrounds (320, 240, 3) for every sensor
    or (L, 320, 240, 3) one per sensor; model: the patch calibration; select: the ``select`` settings (its
    ``align_light``); sensors: the ``sensors`` settings (bodies may overlap as far as their declared pose error
    lets them, ``inputs.body_overlap_margin``). Malformed inputs (shapes, types, poses that are not poses, a
    grey background) raise InputError as in the estimator, since nothing can be read from them; inputs the
    estimator refuses as plausibly wrong are read all the same and their problems listed
    (``SceneReading.refused``). known_units: the no-contact images against which an image is read when it takes
    its own for another unit's (``encode.KnownUnits`` or name -> (320, 240, 3); the estimator's ``known_units``),
    None where the user gave the no-contact images.
    """
    T = inputs.check_sensor_poses(T_world_sensors)
    images = inputs.check_images(images, T.shape[0])
    per_sensor = inputs.backgrounds_per_sensor(inputs.check_backgrounds(backgrounds), T.shape[0])
    scene_problems = []
    try:
        inputs.check_bodies_apart(T, inputs.body_overlap_margin(sensors.pair_distance_tolerance))
    except InputError as exc:
        scene_problems.append(str(exc))
    from tactile6d.perception import encode
    from tactile6d.perception.contact_patch import image_to_patch

    aligned, fits, per_sensor, found = encode.align_light_to_known_units(select, images, per_sensor, known_units)
    units = [None] * len(images) if fits is None else photometric.unit_problems(images, per_sensor, fits)
    sensors = []
    for i, (image, background) in enumerate(zip(images, per_sensor)):
        problem = inputs.image_problem(i, image, background)
        problems = [] if problem is None else [problem]
        try:
            patch = image_to_patch(aligned[i], background, model)
        except InputError as exc:
            patch = None
            problems.append(f"image {i}: {exc}")
        # A grey or BGR image disagrees with any no-contact image: its own problem says why, not the unit's.
        unit = None if problem is not None else units[i]
        sensors.append(SensorReading(image, np.asarray(background), aligned[i], None if fits is None else fits[i],
                                     patch, problems, unit, found[i][0] if i in found else None))
    return SceneReading(sensors, scene_problems)


def contact_summary(patch: ContactPatch | None) -> dict:
    """A patch's figures: ``contact``; with one, ``point_mm`` (sensor frame), ``from_centre_mm`` (its y, z from
    the gel's centre), ``pixel`` (row, column), ``depth_mm`` (deepest press), ``area_percent`` (of the image's
    pixels), ``tilt_deg`` (the surface normal's angle from the camera's axis, sensor x); ``noise`` (grey levels)
    when the image was read."""
    from tactile6d.perception.contact_patch import point_to_pixel

    if patch is None:
        return {"contact": None}
    out = {"contact": bool(patch.contact), "noise": round(float(patch.noise), 2)}
    if patch.contact:
        out.update(
            point_mm=np.round(1000 * patch.point, 2).tolist(),
            from_centre_mm=np.round(1000 * (patch.point - sensor.GEL_CENTER)[1:], 2).tolist(),
            pixel=np.round(point_to_pixel(patch.point), 1).tolist(),
            depth_mm=round(1000 * float(patch.depth.max()), 2),
            area_percent=round(100 * float(patch.mask.mean()), 2),
            tilt_deg=round(float(np.degrees(np.arccos(min(1.0, abs(float(patch.normal[0])))))), 1),
        )
    return out


def sensor_lines(i: int, reading: SensorReading) -> list[str]:
    """One sensor's reading as text: its contact line, its light line, then its problems."""
    c = contact_summary(reading.patch)
    if c["contact"] is None:
        lines = [f"sensor {i}: not read"]
    elif c["contact"]:
        y, z = c["from_centre_mm"]
        lines = [f"sensor {i}: contact at pixel row {c['pixel'][0]:.0f}, column {c['pixel'][1]:.0f} ({y:+.2f} mm across, "
                 f"{z:+.2f} mm along the gel from its centre), pressed {c['depth_mm']:.2f} mm deep over "
                 f"{c['area_percent']:.1f} % of the image, surface tilted {c['tilt_deg']:.0f} deg from the camera's "
                 f"axis; noise {c['noise']:.1f} grey levels"]
    else:
        lines = [f"sensor {i}: no contact (noise {c['noise']:.1f} grey levels)"]
    if reading.light is not None:
        fit = reading.light
        gain = "/".join(f"{v:.2f}" for v in fit.gain)
        gamma = "/".join(f"{v:.2f}" for v in fit.gamma)
        state = "aligned" if fit.applied else "left as given"
        if fit.shading is not None:
            state = (f"the light changes across the gel (a plane of gain per channel, up to {_steepest(fit.shading)} % "
                     f"from its centre to an edge); {state}")
        if fit.level_shift is not None:
            state += (f", then shifted by {'/'.join(f'{v:+.2f}' for v in fit.level_shift)} grey levels onto the level at "
                      "which the renderer's untouched gel sits against its no-contact image")
        lines.append(f"  light: gain {gain}, gamma {gamma} (R/G/B) against its no-contact image, which "
                     f"{100 * fit.agreement:.0f} % of the image and {100 * fit.rim_agreement:.0f} % of its rim follow; {state}")
    if reading.known_unit is not None:
        lines.append(f"  no-contact image: the default looked like another unit's; read against {reading.known_unit}'s, "
                     "which the image agrees with (pass this unit's own for the best reading)")
    lines += [f"  light warning: {p}" for p in reading.light_problems]
    lines += [f"  problem: {p}" for p in reading.problems]
    return lines


def _steepest(shading) -> str:
    """A plane's steepest slope (log gain from the image centre to the middle of an edge) as a per cent change of gain."""
    return f"{100 * (np.exp(float(np.abs(shading).max())) - 1):.0f}"


def reading_figure(reading: SceneReading, title: str):
    """One row per sensor: the image as given, its no-contact image, the difference the reading sees (after
    the light alignment, summed over the channels) and the press depth read from it (mm) with the patch's
    outline and contact point. -> matplotlib Figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(reading.sensors)
    fig, axes = plt.subplots(n, 4, figsize=(10.0, 3.4 * n), squeeze=False)
    for i, (s, row) in enumerate(zip(reading.sensors, axes)):
        difference = np.abs(s.aligned.astype(np.int16) - s.background.astype(np.int16)).sum(axis=-1)
        row[0].imshow(s.image)
        row[0].set_title(f"sensor {i}: image")
        row[1].imshow(s.background)
        row[1].set_title("no-contact image")
        row[2].imshow(difference, cmap="gray", vmin=0, vmax=max(float(np.percentile(difference, 99.5)), 1.0))
        row[2].set_title("|difference| as read")
        c = contact_summary(s.patch)
        if c["contact"]:
            depth = row[3].imshow(1000 * s.patch.depth, cmap="viridis")
            row[3].contour(s.patch.mask, levels=[0.5], colors="white", linewidths=0.8)
            row[3].plot(c["pixel"][1], c["pixel"][0], "r+", markersize=12, markeredgewidth=2)
            fig.colorbar(depth, ax=row[3], fraction=0.046, pad=0.04, label="press (mm)")
            row[3].set_title(f"{c['depth_mm']:.2f} mm deep, tilt {c['tilt_deg']:.0f} deg")
        else:
            row[3].imshow(np.zeros(s.image.shape[:2]), cmap="gray", vmin=0, vmax=1)
            row[3].set_title("no contact" if c["contact"] is False else "not read")
        if s.problems:
            row[0].set_xlabel("refused (see the text)", color="red")
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle("\n".join([title, *reading.problems]), fontsize=9)
    fig.tight_layout()
    return fig


def scene_backgrounds_or_default(scene: Path, n_sensors: int, given: np.ndarray | None, cfg,
                                 own_units: Mapping[str, np.ndarray] | None = None
                                 ) -> tuple[np.ndarray, str, KnownUnits | None]:
    """The no-contact images ``tactile6d estimate`` would read the scene against, which they are, and the known
    units' that an image may be read against instead: those given with ``--background``, else the folder's
    ``background_<i>.png`` (no known units for either), else ``render.background`` and ``encode.KNOWN_UNITS`` with
    ``own_units`` (``--known-units``)."""
    if given is not None:
        return given, "--background", None
    own, _ = scene_backgrounds(scene, n_sensors, False)
    if own is not None:
        return own, "the folder's background_<i>.png", None
    from tactile6d.perception import encode

    return (encode.load_background(cfg), f"render.background ({cfg.render.background})",
            encode.KnownUnits(cfg, own=own_units))


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d inspect", description=description(__doc__))
    parser.add_argument("--scene", required=True, metavar="DIR", help="scene folder: poses_sensors.txt + Image_heatmap_<i>.png")
    parser.add_argument("--background", nargs="+", default=None, metavar="PNG",
                        help="the sensors' no-contact image(s): one for every sensor or one per sensor in sensor "
                             "order (default: the folder's background_<i>.png, else render.background)")
    add_known_units_argument(parser)
    parser.add_argument("--artifacts", default=None, help="artifacts directory holding the patch calibration "
                                                          "(default: paths.artifacts_dir)")
    parser.add_argument("--out", type=Path, default=None, metavar="FILE",
                        help="write the figure there (PNG or JPG; any format matplotlib writes, from the suffix)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the text")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    args = parser.parse_args(argv)
    args.background, overrides = split_overrides(args.background, list(args.overrides))
    args.known_units, overrides = split_overrides(args.known_units, overrides)
    cfg = compose_config(overrides)
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    scene = Path(args.scene)
    T_world_sensors, images = read_scene_dir(scene)
    given = one_scene_background_option(args.background, "inspect")
    own_units = known_units_option(args.known_units, args.background)
    backgrounds, source, known_units = scene_backgrounds_or_default(scene, len(T_world_sensors), given, cfg,
                                                                    own_units)
    from tactile6d.perception import encode

    model = encode.load_patch_model(artifacts)
    reading = read_scene(T_world_sensors, images, backgrounds, model, SelectSettings.from_cfg(cfg.select),
                         SensorSettings.from_cfg(cfg.sensors), known_units)

    if args.out is not None:
        import matplotlib.pyplot as plt

        args.out.parent.mkdir(parents=True, exist_ok=True)
        fig = reading_figure(reading, f"{scene}\nno-contact images: {source}")
        try:
            fig.savefig(args.out, dpi=80)
        except OSError as exc:
            raise DataError(f"cannot write {args.out}: {exc}") from exc
        finally:
            plt.close(fig)
    if args.json:
        print(json.dumps({"scene": str(scene), "backgrounds": source, "refused": reading.refused,
                          "problems": reading.problems, "sensors": [s.to_dict() for s in reading.sensors],
                          "figure": None if args.out is None else str(args.out)}))
    else:
        print(f"{scene}: {len(reading.sensors)} sensors, read against {source}")
        for i, s in enumerate(reading.sensors):
            print("\n".join(sensor_lines(i, s)))
        for problem in reading.problems:
            print(f"problem: {problem}")
        if reading.refused:
            print("tactile6d estimate would refuse this scene (the problems above)")
        if args.out is not None:
            print(f"figure: {args.out}")
    sys.stdout.flush()
    return 1 if reading.refused else 0
