"""A scene set as a real set-up would give it (camera noise, light that drifted, sensor poses off), estimated.

    python scripts/real_setup_check.py --artifacts artifacts --scenes caddeo2023 --conditions clean noise light kinematic
    python scripts/real_setup_check.py --scenes caddeo2023 --conditions light select.align_light=false
    python scripts/real_setup_check.py --scenes caddeo2023 --conditions light kinematic preset=paper
    python scripts/real_setup_check.py --scenes validation --conditions clean jpeg jpeg60 blur
    python scripts/real_setup_check.py --scenes offaxis --conditions slight light

Issue 34's table, on any scene set with images: the paper's 40 triplets (``caddeo2023``) were rendered by
TACTO, another simulator than this project's, so on them it shows whether what the estimator does for real
sensors holds on images it was not built on. Each condition changes only what the estimator is given, with
``tactile6d.sim.perturb`` (the forward models the generated ``variation`` and ``kinematic`` sets are made
with), drawn from ``--seed``:

- ``clean``: the set as it is;
- ``noise``: camera noise of 2 grey levels on every image;
- ``light``: each sensor's own gain per channel (1 +- 0.1) and gamma (0.83-1.2), then noise 2, the no-contact
  image not recorded again (what a unit whose LEDs drifted gives);
- ``slight``: as ``light``, but a gain per channel of 1 +- 0.03 only (no gamma): a unit's LEDs minutes after
  its no-contact image was recorded, or an exposure step; a change of one or two grey levels, which the
  alignment must not leave to the contact mask;
- ``kinematic``: each sensor pose off by 1.5 mm and 1.5 deg per axis (Gaussian, sensor frame), the images
  those of the true poses;
- ``jpeg``: every image and no-contact image JPEG-compressed at quality 80, as a DIGIT's MJPEG stream
  delivers them (``perturb.through_camera``); ``jpeg60`` and ``jpeg90`` at quality 60 and 90;
- ``blur``: every image and no-contact image blurred by a Gaussian of 1 pixel (a lens slightly out of focus);
- ``recorded+1``, ``recorded-1``: each sensor's no-contact image one grey level brighter or darker than the
  images' exposure (every pixel; recorded at another exposure step, or rounded where the camera truncates): too
  small a change for the light's fit to be applied, left to ``photometric``'s untouched level (``--no-level-shift``:
  as before it, every image read at its level).
- ``shading``, ``shading10``: light that changed unevenly over the gel, as when one of a DIGIT's LEDs, each on its
  own side, dims or brightens more than the others: each sensor's gain per channel a ramp across the image, 1 at
  the centre and 1 +- 0.05 (``shading10``: 0.10) at the edge the ramp points to, in a direction drawn per channel;
  then noise 2, the no-contact image not recorded again (``shade_image``). The light's fit models one gain and
  gamma per channel for the whole image, not this.
- ``other-unit``: every image moved onto another DIGIT unit, TACTO's example unit (``OTHER_UNIT``): its difference
  from the no-contact image it was rendered over added to that unit's no-contact image (as both renderers add a
  press to the background), clipped to 8 bits; no no-contact image passed, as a user who never recorded one
  gives it (the issue's "another DIGIT unit, no-contact image not passed"); ``other-unit-own``: the same with that
  unit's no-contact image passed.
- ``drawer``: a hand of units from a lab's drawer: each sensor's image moved (as for ``other-unit``) onto its own
  unit, three distinct units per scene drawn from six (``drawer_units``: the data directory's two units' no-contact
  images turned half a turn and mirrored either way, six LED layouts that agree with none of the others nor with
  the two), no no-contact image passed; ``drawer-known``: the same images with the six given as known units
  (``tactile6d estimate --known-units``); ``drawer-own``: each sensor's own unit's no-contact image passed. The
  three draw the same units.
- ``tacto-size``, ``vga``: every image and its no-contact image at another resolution of the same field of view,
  passed at that size (the estimator reads them resized to 240 x 320, ``hdf5.to_tactile_size``): ``tacto-size``
  120 x 160, what TACTO renders by default, each pixel the mean of the 2 x 2 it covers; ``vga`` 480 x 640, a DIGIT
  streamed at VGA, enlarged bilinear from the set's images (``at_size``).

Each scene is estimated with the online estimator (default settings, or the overrides given) and scored as
the evaluation scores it; one JSON line per condition: the positional error of the best pose, mean and
median over scenes (cm), the share of scenes whose best pose is within 2 cm ADI, the ADI-AUC figures
averaged over objects and the failures; ``--out PREFIX`` also writes each condition's per-scene errors to
``PREFIX<condition>.npz``, which ``scripts/compare_errors.py`` pairs scene by scene with another run's. ``--light-fits`` adds how well the light was fitted (``clean``, ``light`` and ``slight``):
over the images, the median and 90th percentile of the fit's error against the drift drawn (none
for ``clean``), in gain and gamma (the channel farthest off), the share of blocks outside the fit and how many
images the fit was applied to (``photometric.align_images``, the fits the estimator makes). ``--confidence`` adds
how the estimates' calibrated confidence sorts them (``Estimate.confidence``, P(best pose within 1 cm ADI)): its
AUROC for that success, the share right and the mean confidence, and the share flagged ambiguous. The test set is
looked at after a decision, never to make one: tune on the generated sets.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.estimation import confidence as confidence_model
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.evaluation.metric_table import ERROR_KEYS
from tactile6d.evaluation.sensor_subsets import estimate_and_score
from tactile6d.perception import photometric
from tactile6d.perception.encode import KnownUnits, load_background
from tactile6d.runtime.script_args import parse_with_overrides
from tactile6d.sim import perturb, scenes
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

CONDITIONS = ("clean", "noise", "light", "kinematic", "jpeg", "jpeg60", "blur", "jpeg90", "slight", "recorded+1", "recorded-1",
              "shading", "shading10", "other-unit", "other-unit-own", "drawer", "drawer-known", "drawer-own",
              "tacto-size", "vga")
OTHER_UNIT = "digit/tacto/bg_digit_240_320.jpg"  # TACTO's example DIGIT's no-contact image, in the data directory
ISSUE_CONDITIONS = CONDITIONS[:4]  # issue 34's table: the default
JPEG_QUALITY = {"jpeg": 80, "jpeg60": 60, "jpeg90": 90}
BLUR_SIGMA = 1.0  # pixels
NOISE_STD = 2.0  # grey levels
GAIN_MAX, GAMMA_RANGE = 0.10, (0.83, 1.20)
SLIGHT_GAIN_MAX = 0.03  # condition slight: gains only, 1 +- 0.03 per channel
SIGMA_MM, SIGMA_DEG = 1.5, 1.5
RECORDED = {"recorded+1": 1, "recorded-1": -1}  # grey levels added to every no-contact image
SHADING = {"shading": 0.05, "shading10": 0.10}  # the ramp's gain change from the image centre to its edge
ADI_WITHIN = 0.02  # m: the share of scenes whose best pose is this close (ADI) is reported


DRAWER_CONDITIONS = ("drawer", "drawer-known", "drawer-own")
SIZES = {"tacto-size": (160, 120), "vga": (640, 480)}  # rows x columns the images are given at


def at_size(images: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Images (..., 320, 240, 3) uint8 -> (..., rows, cols, 3): averaged over the pixels each covers when smaller
    (OpenCV's INTER_AREA), bilinear when larger: the same field of view at another resolution."""
    import cv2

    flat = images.reshape(-1, *images.shape[-3:])
    how = cv2.INTER_AREA if rows < images.shape[-3] else cv2.INTER_LINEAR
    out = np.stack([cv2.resize(np.ascontiguousarray(image), (cols, rows), interpolation=how) for image in flat])
    return out.reshape(*images.shape[:-3], rows, cols, 3)


def drawer_units(units: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Six units' no-contact images (320, 240, 3) uint8 RGB for the ``drawer`` conditions, from units (name -> image):
    each turned half a turn ("turned"), mirrored left-right ("mirrored") and up-down ("flipped"): the LEDs laid out
    otherwise."""
    flips = {"turned": (slice(None, None, -1), slice(None, None, -1)), "mirrored": (slice(None), slice(None, None, -1)),
             "flipped": (slice(None, None, -1), slice(None))}
    return {f"{name} {how}": np.ascontiguousarray(image[index]) for name, image in units.items()
            for how, index in flips.items()}


def move_onto_units(images: np.ndarray, background: np.ndarray, units: np.ndarray) -> np.ndarray:
    """Images (..., 320, 240, 3) uint8 rendered over background (320, 240, 3), each moved onto its unit (units of
    the images' shape, or broadcast to it): its difference from the background added to the unit's no-contact image,
    as both renderers add a press to the background, clipped to 8 bits."""
    moved = images.astype(np.int16) - background.astype(np.int16) + units.astype(np.int16)
    return np.clip(moved, 0, 255).astype(np.uint8)


def real_set_up(scene_set: scenes.SceneSet, condition: str, background: np.ndarray,
                rng: np.random.Generator, other_unit: np.ndarray | None = None,
                drawer: dict[str, np.ndarray] | None = None) -> scenes.SceneSet:
    """``scene_set`` under one of CONDITIONS (module docstring); background (320, 240, 3) uint8 RGB, the
    no-contact image its images were rendered over; other_unit (320, 240, 3) uint8 RGB, ``OTHER_UNIT``'s (for the
    ``other-unit`` conditions); drawer: name -> (320, 240, 3) uint8 RGB, the units of the ``drawer`` conditions, which
    record each sensor's unit's index in ``extra["unit"]`` (S, L). The truth (object poses, contacts) is unchanged."""
    if condition == "clean" or condition in SIZES:
        return scene_set  # SIZES: the images are given at another size when estimated (main)
    if condition in ("other-unit", "other-unit-own"):
        own = np.broadcast_to(other_unit, scene_set.images.shape) if condition == "other-unit-own" else None
        return replace(scene_set, images=move_onto_units(scene_set.images, background, other_unit), backgrounds=own)
    if condition in DRAWER_CONDITIONS:
        n_scenes, n_sensors = scene_set.images.shape[:2]
        library = np.stack(list(drawer.values()))
        drawn = np.stack([rng.choice(len(library), n_sensors, replace=False) for _ in range(n_scenes)])
        units = library[drawn]
        return replace(scene_set, images=move_onto_units(scene_set.images, background, units),
                       backgrounds=units if condition == "drawer-own" else None,
                       extra={**scene_set.extra, "unit": drawn})
    if condition == "noise":
        return replace(scene_set, images=perturb.add_camera_noise(scene_set.images, NOISE_STD, rng))
    if condition == "light":
        return perturb.drift_light(scene_set, background, GAIN_MAX, GAMMA_RANGE, NOISE_STD, 0.0, rng)
    if condition == "slight":
        return perturb.drift_light(scene_set, background, SLIGHT_GAIN_MAX, (1.0, 1.0), NOISE_STD, 0.0, rng)
    if condition == "kinematic":
        return perturb.perturb_sensor_poses(scene_set, 1e-3 * SIGMA_MM, np.radians(SIGMA_DEG), rng)
    if condition in JPEG_QUALITY:
        return perturb.through_camera(scene_set, background, jpeg_quality=JPEG_QUALITY[condition])
    if condition == "blur":
        return perturb.through_camera(scene_set, background, blur_sigma=BLUR_SIGMA)
    if condition in SHADING:
        return shade_light(scene_set, background, SHADING[condition], rng)
    if condition in RECORDED:
        shifted = np.clip(background.astype(np.int16) + RECORDED[condition], 0, 255).astype(np.uint8)
        return replace(scene_set, backgrounds=np.broadcast_to(shifted, scene_set.images.shape))
    raise ValueError(f"unknown condition {condition!r}; choose from {CONDITIONS}")


def shade_image(image: np.ndarray, slopes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """image (H, W, 3) uint8 under light whose gain varies across it: per channel c a ramp ``1 + slopes[c] t``,
    t the pixel's position along the direction ``angles[c]`` (rad, in the image plane), scaled so that t = 1 where
    the direction meets the image's edge from its centre (and -1 opposite); slopes, angles (3,). Rounded to 8 bits.
    Kept with this check rather than in ``tactile6d.sim.perturb`` while no generated set is made with it."""
    v, u = photometric.centred_coordinates(image.shape[:2])
    out = np.empty(image.shape, dtype=np.float64)
    for c in range(3):
        d = np.array([np.cos(angles[c]), np.sin(angles[c])])  # (row, col) direction
        t = (v[:, None] * d[0] + u[None, :] * d[1]) / np.abs(d).max()  # 1 at the edge the direction points to
        out[..., c] = image[..., c] * (1.0 + slopes[c] * t)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def shade_light(scene_set: scenes.SceneSet, background: np.ndarray, slope_max: float,
                rng: np.random.Generator) -> scenes.SceneSet:
    """``scene_set`` with each sensor's light shaded (``shade_image``: per channel a slope of ``slope_max`` in a
    direction drawn uniformly), then camera noise ``NOISE_STD``; each sensor's no-contact image the one rendered
    over, background (320, 240, 3) uint8 RGB, or the set's own, not recorded again."""
    n, L = scene_set.images.shape[:2]
    slopes, angles = np.full((n, L, 3), slope_max), rng.uniform(0.0, 2.0 * np.pi, (n, L, 3))
    images = np.empty_like(scene_set.images)
    backgrounds = np.empty_like(scene_set.images)
    for s in range(n):
        own = scene_set.backgrounds_of(s)
        for i in range(L):
            images[s, i] = perturb.add_camera_noise(shade_image(scene_set.images[s, i], slopes[s, i], angles[s, i]),
                                                    NOISE_STD, rng)
            backgrounds[s, i] = background if own is None else own[i]
    return replace(scene_set, images=images, backgrounds=backgrounds)


def drift_drawn(scene_set: scenes.SceneSet, s: int) -> tuple[np.ndarray, np.ndarray]:
    """Scene s's light drift per sensor, gain and gamma (L, 3) each: the drawn one, or none (ones)."""
    shape = scene_set.images.shape[1:2] + (3,)
    if "light_gain" not in scene_set.extra:
        return np.ones(shape), np.ones(shape)
    return np.asarray(scene_set.extra["light_gain"][s]), np.asarray(scene_set.extra["light_gamma"][s])


def light_fit_row(fits: list, gains: np.ndarray, gammas: np.ndarray) -> dict[str, float]:
    """How well the light was fitted: fits, one ``photometric.LightFit`` per image; gains, gammas (N, 3) the
    drift drawn for each image -> the median and 90th percentile over images of the farthest channel's error
    in gain and gamma, the mean share of blocks outside the fit, and how many fits were applied."""
    gain_err = np.array([np.abs(f.gain - g).max() for f, g in zip(fits, gains)])
    gamma_err = np.array([np.abs(f.gamma - e).max() for f, e in zip(fits, gammas)])
    return {"gain_err_median": round(float(np.median(gain_err)), 4), "gain_err_p90": round(float(np.percentile(gain_err, 90)), 4),
            "gamma_err_median": round(float(np.median(gamma_err)), 4),
            "gamma_err_p90": round(float(np.percentile(gamma_err, 90)), 4),
            "outliers_mean": round(float(np.mean([f.outliers for f in fits])), 3),
            "applied": int(sum(bool(f.applied) for f in fits)), "images": len(fits)}


def write_errors(path: str, objects: np.ndarray, errors: dict[str, np.ndarray]) -> None:
    """One condition's per-scene errors (as ``summary_row`` takes them) and objects (S,) to an npz file in
    the layout of ``eval_accuracy.py --out``, which ``compare_errors.py`` reads."""
    np.savez(path, objects=np.asarray(objects), **errors)


class RecordingEstimator:
    """An estimator that keeps the last estimate it made, for the figures ``estimate_and_score`` does not return
    (the confidence and the ambiguity flag)."""

    def __init__(self, estimator: Estimator):
        self.estimator, self.last = estimator, None

    def estimate(self, *args, **kwargs):
        self.last = None  # an estimate that raises leaves nothing behind
        self.last = self.estimator.estimate(*args, **kwargs)
        return self.last


def confidence_row(confidence: np.ndarray, ambiguous: np.ndarray, top1_adi: np.ndarray) -> dict[str, float]:
    """Scenes' confidences (S,) (NaN where no estimate), ambiguity flags (S,) and best-pose ADI (S,) m -> the
    confidence's AUROC for ADI under ``confidence.SUCCESS_ADI``, the share right, the mean confidence and the share
    flagged ambiguous (failed estimates count as wrong, with confidence 0)."""
    right = np.nan_to_num(top1_adi, nan=np.inf) < confidence_model.SUCCESS_ADI
    p = np.nan_to_num(confidence, nan=0.0)
    return {"confidence_auroc": round(float(confidence_model.auroc(p, right)), 3),
            "share_right_pct": round(100.0 * float(right.mean()), 1),
            "mean_confidence_pct": round(100.0 * float(p.mean()), 1),
            "ambiguous_pct": round(100.0 * float(np.mean(ambiguous)), 1)}


def summary_row(errors: dict[str, np.ndarray], objects: np.ndarray) -> dict[str, float]:
    """The figures of one condition: errors as ``scoring.scene_errors`` gives them, stacked over scenes
    (S, K), objects (S,) -> the best pose's positional error mean and median (cm), the share within
    ADI_WITHIN (%), and the ADI-AUC figures of ``scoring.summarise_by_object``'s average (%)."""
    average = scoring.summarise_by_object(errors, objects)["average"]
    top1_adi = np.asarray(errors["adi"])[:, 0]
    return {"pos_err_cm_mean": round(100.0 * float(np.nanmean(np.asarray(errors["position"])[:, 0])), 2),
            "pos_err_cm_median": round(average["pos_err_cm_top1_median"], 2),
            "adi_within_2cm_pct": round(100.0 * float(np.mean(np.nan_to_num(top1_adi, nan=np.inf) < ADI_WITHIN)), 1),
            "adi_auc_paper_top1": round(average["adi_auc_paper_top1"], 2),
            "adi_auc_std_top1": round(average["adi_auc_std_top1"], 2)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", default="caddeo2023", help="a scene set with images under artifacts/scenes")
    parser.add_argument("--conditions", nargs="+", default=list(ISSUE_CONDITIONS), choices=CONDITIONS,
                        help="default: issue 34's four (clean noise light kinematic)")
    parser.add_argument("--seed", type=int, default=0, help="of the perturbations drawn")
    parser.add_argument("--light-fits", action="store_true", help="also how well the light was fitted (module docstring)")
    parser.add_argument("--confidence", action="store_true", help="also how the confidence sorts the estimates")
    parser.add_argument("--out", help="write each condition's per-scene errors to OUT<condition>.npz (as eval_accuracy.py "
                                      "--out does), for scripts/compare_errors.py")
    parser.add_argument("--no-level-shift", action="store_true",
                        help="leave every image at its untouched level (photometric.LEVEL_TOLERANCE infinite): as before 2026-12-07")
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. preset=paper")
    args = parse_with_overrides(parser)
    if args.no_level_shift:
        photometric.LEVEL_TOLERANCE = np.inf

    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    clean = scenes.scene_set_from_artifact(read_artifact(layout.scenes_file(args.artifacts, args.scenes), "scenes"))
    estimators = {o: Estimator.from_artifacts(o, args.artifacts, cfg) for o in dict.fromkeys(clean.objects.tolist())}
    references = {o: scoring.load_object_reference(args.artifacts, o) for o in estimators}
    background = next(iter(estimators.values())).no_contact  # the one the set was rendered over: the default
    other_unit = load_background({"render": {"background": OTHER_UNIT}, "paths": cfg.paths})
    drawer = drawer_units(KnownUnits(cfg).images())
    with_drawer = None  # the estimators that know the drawer's units, for drawer-known
    for condition in args.conditions:
        # The drawer's three conditions draw the same units.
        draw = "drawer" if condition in DRAWER_CONDITIONS else condition
        scene_set = real_set_up(clean, condition, background, np.random.default_rng((args.seed, CONDITIONS.index(draw))),
                                other_unit, drawer)
        chosen = estimators
        if condition == "drawer-known":
            with_drawer = with_drawer or {o: Estimator.from_artifacts(o, args.artifacts, cfg, known_units=drawer)
                                          for o in estimators}
            chosen = with_drawer
        rows, failed, confidences, ambiguous = {key: [] for key in ERROR_KEYS}, 0, [], []
        for s, obj in enumerate(clean.objects.tolist()):
            images, own = scene_set.images[s], scene_set.backgrounds_of(s)
            if condition in SIZES:
                images = at_size(images, *SIZES[condition])
                own = at_size(background if own is None else own, *SIZES[condition])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                recorder = RecordingEstimator(chosen[obj])
                scored = estimate_and_score(recorder, scene_set.T_world_sensors[s], images,
                                            scene_set.T_world_object[s], references[obj], own)
            failed += scored.seconds is None
            estimate = recorder.last
            confidences.append(np.nan if estimate is None or estimate.confidence is None else estimate.confidence)
            ambiguous.append(bool(estimate is not None and estimate.ambiguous))
            for key, values in rows.items():
                values.append(scored.errors[key])
        errors = {key: np.array(v) for key, v in rows.items()}
        if args.out:
            write_errors(f"{args.out}{condition}.npz", clean.objects, errors)
        light = {}
        if args.light_fits and condition in ("clean", "light", "slight"):
            # The estimator's own fits (select.align_light): each image against its sensor's no-contact image.
            fits = [fit for s, obj in enumerate(clean.objects.tolist())
                    for fit in photometric.align_images(scene_set.images[s], estimators[obj].backgrounds(
                        len(scene_set.images[s]), scene_set.backgrounds_of(s)))[1]]
            drawn = [drift_drawn(scene_set, s) for s in range(len(clean))]
            light = {"light_fits": light_fit_row(fits, np.concatenate([g for g, _ in drawn]),
                                                 np.concatenate([e for _, e in drawn]))}
        print(json.dumps({"scenes": args.scenes, "condition": condition, "overrides": args.overrides,
                          **({"no_level_shift": True} if args.no_level_shift else {}),
                          "seed": args.seed, "n": len(clean), "failed": int(failed),
                          **summary_row(errors, clean.objects), **light,
                          **(confidence_row(np.array(confidences), np.array(ambiguous), errors["adi"][:, 0])
                             if args.confidence else {})}), flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
