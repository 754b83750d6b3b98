"""The contact patch of one tactile image: where the object presses, how deep, its contact point and normal.

Input: one DIGIT image (320, 240, 3) uint8 RGB and the same sensor's no-contact image. Everything is
computed from their difference, so the unit's own background (its vignetting, its LEDs' tint) cancels;
the simulator's background is never needed.

The method is GelSight-style photometric stereo, calibrated on simulated presses of known shape:

1. Difference image ``D = image - no_contact`` (float, RGB). The per-pixel noise level is estimated from
   the image itself (the median absolute Laplacian residual), so thresholds adapt to the unit and to
   whether the no-contact image is noisy or clean.
2. Mask: hysteresis on the magnitude of the Gaussian-smoothed difference (seeds well above the smoothed
   noise, measured on the smoothed difference itself where a JPEG stream or a blur has made the noise
   other than white; grown through pixels moderately above it, small blobs dropped), then its convex hull, eroded
   by the spread that the sensor's blur and the smoothing add to the imprint. The hull, because the
   region where a locally convex object is in front of the convex gel is convex (a sublevel set of a
   convex function); without it, parts of the imprint whose slope matches the gel's show almost no
   colour change, fall out of the mask and are wrongly held at zero depth.
3. Surface normals: a polynomial regression from (smoothed RGB difference, ray direction) to the two
   lateral components of the visible surface's unit normal, evaluated on 2 x 2 pixel blocks. The
   DIGIT's lights are point lights a few millimetres from the gel, so the same colour means a different
   slope at different pixels: hence the ray direction among the inputs. Where the mask overshoots, the
   visible surface is the gel itself, whose normal is known, so the regression learns "gel" for a faint
   difference. A third output regresses the press depth directly (the lights are closer to a deeper
   surface); it is a weak cue, used only to fix the depth when the mask has no edge inside the image.
4. Depth: the camera is a pinhole, so with ``t`` the distance along the camera axis of the surface point
   seen through ray ``(1, u, v)`` and ``n`` its normal, ``d log t / du = -n_y / (n . r)`` and
   ``d log t / dv = -n_z / (n . r)``. ``log t`` is integrated by least squares over the mask on a coarser
   grid, held at the gel's own ``log t`` just outside the mask (the object leaves the gel there: press
   depth zero), free at the image border. Press depth = gel distance - t, the quantity
   ``render.RenderResult.depth`` defines.
5. Contact point: the mean of the object's surface points (``camera + t * ray``) over the pixels pressed
   within ``top_band`` (a fraction of the deepest press) of the deepest, weighted by how far into that
   band they go. It is the deepest point made robust to the noise of a single pixel and to flat
   contacts, whose deepest pixel is ill-defined; for a flat face pressed square into the gel apex it is
   the surface point on the gel axis, next to the landmark ``sensor.CONTACT_POINT``. Normal: the same
   weighted mean of the estimated normals, normalised.

Calibration (``calibrate``): random superquadrics (spheres, ellipsoids, boxes, edges, corners) pressed
at random depths, offsets and tilts, rendered by ``render.DigitRenderer`` over a flat grey background
(so nothing clips); the true normal of every pressed pixel comes from the shape's analytic normal at the
surface point its true depth gives. Fitting is one linear least-squares solve.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.linalg

from tactile6d.core import sensor
from tactile6d.core.config import default_section
from tactile6d.core.errors import DataError, InputError
from tactile6d.core.geometry import axis_angle_to_rotmat, invert_pose, make_pose
from tactile6d.data.hdf5 import tactile_shape_problem
from tactile6d.sim import superquadrics as sq
from tactile6d.sim.render import CAMERA_POSITION, CAMERA_YFOV, DigitRenderer, gel_surface, mesh_arrays, pixel_rays

H, W = sensor.IMAGE_HEIGHT, sensor.IMAGE_WIDTH
IMAGE_SHAPE = (H, W, 3)
_FOCAL = (H / 2.0) / np.tan(np.deg2rad(60.0) / 2.0)  # pixels; the renderer's camera

# Saturated pixels carry no shading information; an image mostly saturated is not a tactile reading.
_MAX_SATURATED_FRACTION = 0.5

# Steepest normal the regression may report (sine of its angle to the camera axis): a gel pressed 2.5 mm
# by a 5 mm sphere meets it 60 deg off axis; steeper predictions come from sharp features the blur has
# smeared, and near-grazing slopes would blow up the depth integration.
_MAX_LATERAL = np.sin(np.deg2rad(65.0))

_MODEL_FORMAT = "tactile6d.patch/1"


@dataclass(frozen=True)
class PatchModel:
    """Calibration of the colour-to-normal regression and of the mask thresholds.

    coefficients (F, 3) float64: polynomial weights giving the normal's (y, z) components and the press
    depth in millimetres (a weak cue: the lights are closer to a deeper surface); degree: of the
    polynomial in the five inputs (three scaled colour differences, u, v); colour_scale: grey levels per
    unit input; sigma (pixels): Gaussian smoothing of the difference image before the regression;
    mask_sigma (pixels): the same for the mask; seed_level, grow_level: the hysteresis thresholds of the
    mask, in units of the smoothed noise's standard deviation; erode (pixels): radius the mask is eroded
    by; min_area (pixels): smaller connected blobs are dropped; grid_step (pixels): the depth integration
    grid; top_band: fraction of the deepest press that defines the contact region; convex: take the
    mask's convex hull (see the module docstring).
    """

    coefficients: np.ndarray
    degree: int = 3
    colour_scale: float = 64.0
    sigma: float = 2.0
    mask_sigma: float = 2.0
    seed_level: float = 7.0
    grow_level: float = 5.0
    erode: int = 2
    min_area: int = 150
    grid_step: int = 4
    top_band: float = 0.1
    convex: bool = True


@dataclass(frozen=True)
class ContactPatch:
    """What one tactile image says about the contact, in the sensor (DIGIT) frame.

    contact: False when the image shows no contact (then point and normal are None, mask all False,
    depth all zero). mask (320, 240) bool; depth (320, 240) float32 metres, how far the object presses
    into the gel along the sensor's +x axis (0 outside the mask); point (3,) metres, the object's surface
    point at the contact (see the module docstring); normal (3,) unit, the object's outward surface
    normal there; noise: estimated noise standard deviation of the difference image, grey levels.
    The mask is the region the depth is integrated over (see ``difference_to_mask``).
    """

    contact: bool
    mask: np.ndarray
    depth: np.ndarray
    point: np.ndarray | None
    normal: np.ndarray | None
    noise: float


# --- the fixed geometry of the camera and gel -----------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _camera_geometry() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rays (H, W, 3) with x = 1; gel distance t (H, W) along +x; gel unit normals (H, W, 3) facing the camera."""
    rays = pixel_rays(W, H)
    points, normals = gel_surface(rays)
    t_gel = points[..., 0] - CAMERA_POSITION[0]
    for a in (rays, t_gel, normals):
        a.setflags(write=False)
    return rays, t_gel, normals


@functools.lru_cache(maxsize=4)
def _block_geometry(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the centres of k x k pixel blocks (H/k, W/k, 3) and the gel's mean normals there."""
    rays = pixel_rays(W, H, k)
    normals = _block_mean(_camera_geometry()[2], k)
    for a in (rays, normals):
        a.setflags(write=False)
    return rays, normals


@functools.lru_cache(maxsize=1)
def _geometry_planes() -> tuple[np.ndarray, np.ndarray]:
    """The rays and the gel normals of ``_camera_geometry`` as component planes (3, H, W), contiguous copies:
    a box of one plane is then read row by row rather than every third number."""
    rays, _, normals = _camera_geometry()
    planes = tuple(np.ascontiguousarray(np.moveaxis(a, -1, 0)) for a in (rays, normals))
    for a in planes:
        a.setflags(write=False)
    return planes


@functools.lru_cache(maxsize=4)
def _coarse_gel(k: int) -> tuple[np.ndarray, np.ndarray]:
    """The gel's ``log t`` on the k x k cells of the depth grid (H/k, W/k) and its exp (the same arrays that
    ``normals_to_depth`` used to recompute per image: the same calls on the same values, hence the same bits)."""
    log_gel = np.log(_block_mean(_camera_geometry()[1], k))
    gel_t = np.exp(log_gel)
    for a in (log_gel, gel_t):
        a.setflags(write=False)
    return log_gel, gel_t


def gel_distance() -> np.ndarray:
    """(320, 240) float64 metres: the camera-axis distance of the unpressed gel seen by each pixel."""
    return _camera_geometry()[1]


# --- input checks ------------------------------------------------------------------------------------


def check_image(image, name: str = "image") -> np.ndarray:
    """A tactile image -> (320, 240, 3) uint8 array. Raises InputError naming what is wrong."""
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise InputError(f"{name} has dtype {a.dtype}; a tactile image is uint8")
    problem = tactile_shape_problem(a.shape, name)
    if problem is not None:
        raise InputError(problem)
    return a


def images_to_difference(image, no_contact) -> np.ndarray:
    """image, no_contact: (320, 240, 3) uint8 RGB of the same sensor -> D (320, 240, 3) float32 grey levels.

    Raises InputError for a wrong shape or dtype, or when more than half of the image's pixels are
    saturated (0 or 255 in a channel where the no-contact image is not), which leaves no shading to read.
    """
    img = check_image(image, "image")
    bg = check_image(no_contact, "no-contact image")
    # 0 or 255 where the no-contact image differs; img - 1 wraps 0 to 255, so one comparison finds both ends
    clipped = (np.subtract(img, 1, dtype=np.uint8) >= 254) & (img != bg)
    per_channel = clipped.reshape(-1, 3)
    # the pixel count is exact, so this is the same fraction np.mean(np.any(clipped, axis=-1)) gives
    saturated = np.count_nonzero(per_channel[:, 0] | per_channel[:, 1] | per_channel[:, 2]) / per_channel.shape[0]
    if saturated > _MAX_SATURATED_FRACTION:
        raise InputError(f"{saturated:.0%} of the tactile image's pixels are saturated (0 or 255): no contact shading to read")
    return np.subtract(img, bg, dtype=np.float32)  # whole grey levels, exact in float32


# --- moving a contact to the image centre -----------------------------------------------------------------


def point_to_pixel(point: np.ndarray) -> np.ndarray:
    """Where the camera sees a point: point (..., 3) m, sensor frame, in front of the camera -> (..., 2)
    (row, column) in pixels, continuous, pixel (i, j) covering [i, i + 1) x [j, j + 1): the inverse of
    ``render.pixel_rays``. The image centre (160, 120) looks along +x, through the gel's apex."""
    rel = np.asarray(point, dtype=np.float64) - CAMERA_POSITION
    focal = (H / 2.0) / np.tan(CAMERA_YFOV / 2.0)
    return np.stack([H / 2.0 - focal * rel[..., 2] / rel[..., 0], W / 2.0 - focal * rel[..., 1] / rel[..., 0]], axis=-1)


def shift_difference(image: np.ndarray, no_contact: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The image with its difference from the no-contact image moved by whole pixels: (320, 240, 3) uint8
    RGB x2 -> (320, 240, 3) uint8 RGB, the no-contact image where the moved difference leaves none.

    rows > 0 moves the contact down (toward -z), cols > 0 right (toward -y). Used to put an off-centre
    contact where the database's contacts are, at the centre, before the autoencoder reads it.
    """
    img, bg = check_image(image, "image"), check_image(no_contact, "no-contact image")
    diff = img.astype(np.int16) - bg.astype(np.int16)
    moved = np.zeros_like(diff)
    rows, cols = int(np.clip(rows, -H, H)), int(np.clip(cols, -W, W))
    moved[max(rows, 0):H + min(rows, 0), max(cols, 0):W + min(cols, 0)] = \
        diff[max(-rows, 0):H + min(-rows, 0), max(-cols, 0):W + min(-cols, 0)]
    return np.clip(bg.astype(np.int16) + moved, 0, 255).astype(np.uint8)


def centre_contact(image: np.ndarray, no_contact: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The image moved so that the contact at ``point`` (3,) m, sensor frame (``ContactPatch.point``),
    appears at the image centre (``shift_difference``, to the nearest pixel)."""
    row, col = point_to_pixel(point)
    return shift_difference(image, no_contact, int(np.rint(H / 2.0 - row)), int(np.rint(W / 2.0 - col)))


# --- noise, smoothing, mask --------------------------------------------------------------------------------


def difference_to_noise(diff: np.ndarray) -> float:
    """D (H, W, 3) -> float: the standard deviation of its per-pixel noise, grey levels.

    The residual of each pixel against the mean of its four neighbours has variance 1.25 sigma^2 for
    white noise, and almost no signal since the tactile imprint is smooth; the median absolute value
    (times 1.4826) makes it robust to the imprint's edges.
    """
    lap = diff[1:-1, 1:-1] - 0.25 * (diff[:-2, 1:-1] + diff[2:, 1:-1] + diff[1:-1, :-2] + diff[1:-1, 2:])
    return _median_to_noise(np.median(np.abs(lap)))


def _median_to_noise(median) -> float:
    """The median absolute residual (a NumPy float32 scalar, as ``np.median`` of float32 gives) -> noise std."""
    return float(1.4826 * median / np.sqrt(1.25))


# Residuals of a whole-grey-level D are multiples of 1/4 with |4 * residual| <= 8 * 255.
_RESIDUAL_LEVELS = 8 * 255 + 1


def _whole_level_noise(diff: np.ndarray) -> float:
    """``difference_to_noise(diff)`` for a D (H, W, 3) of whole grey levels (what ``images_to_difference``
    returns), the same number, found from a histogram instead of a partial sort.

    For such a D, ``4 * residual`` is an integer of at most 2040 in magnitude, and the float32 residuals
    the general function computes are exactly those integers / 4 (every sum on the way is exact), so the
    median's two middle values, and their float32 mean ``np.median`` returns, follow from the counts.
    """
    d = diff.astype(np.int16)
    lap4 = 4 * d[1:-1, 1:-1] - (((d[:-2, 1:-1] + d[2:, 1:-1]) + d[1:-1, :-2]) + d[1:-1, 2:])
    levels = np.abs(lap4).view(np.uint16).reshape(lap4.shape[0], -1)
    # OpenCV's histogram of 16-bit values with unit bins is exact and several times faster than np.bincount
    counts = cv2.calcHist([levels], [0], None, [_RESIDUAL_LEVELS], [0, _RESIDUAL_LEVELS]).ravel().astype(np.int64)
    below = np.cumsum(counts)
    n = lap4.size
    if below[-1] != n:  # not whole grey levels after all (cannot happen for images_to_difference's D)
        return difference_to_noise(diff)
    half = n // 2
    upper = int(np.searchsorted(below, half, side="right"))  # the value * 4 of the half-th smallest (0-based)
    if n % 2:
        return _median_to_noise(np.float32(upper / 4.0))
    lower = int(np.searchsorted(below, half - 1, side="right"))
    return _median_to_noise(np.float32((lower + upper) / 8.0))  # exact: a multiple of 1/8 below 1024


def smooth_difference(diff: np.ndarray, sigma: float) -> np.ndarray:
    """D (H, W, 3) -> Gaussian-smoothed D, same shape, float32 (standard deviation ``sigma`` pixels)."""
    return cv2.GaussianBlur(np.asarray(diff, dtype=np.float32), (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def smoothed_noise(noise: float, sigma: float) -> float:
    """Standard deviation of white noise of std ``noise`` after a 2D Gaussian of ``sigma`` pixels."""
    return noise / (2.0 * np.sqrt(np.pi) * sigma)


# Noise that is not white: a camera's JPEG stream or a lens out of focus blurs the noise along with the image,
# so the per-pixel residual (``difference_to_noise``) sees little of it while the smoothed D keeps most of it.
# The smoothed D's own noise is then measured from residuals between pixels some smoothing sigmas apart
# (``far_residual_noise``). At CORRELATED_TEST sigmas that measure is within 1.25 times the white-noise formula
# on every image of the pipeline's scene sets (TACTO's included; at most 1.1 on this renderer's), so the formula
# is kept unless the measure is CORRELATED_RATIO times larger: images with white noise get the mask they always
# got. Noise blurred by JPEG at quality 80, or by a Gaussian of half a pixel, measures 1.8-9 times it. The level
# is then read at CORRELATED_LEVEL sigmas, where the smoothed white noise has decorrelated (at 3 sigmas it still
# correlates by about 0.1 and reads low).
CORRELATED_TEST = 3.0
CORRELATED_LEVEL = 4.0
CORRELATED_RATIO = 1.5

# The mask's thresholds never fall below those of D noise of MIN_NOISE grey levels. The mask's edge, where the
# blurred imprint fades into the gel, was set (the erosion, the calibration) on the renderer's noise, 7 grey
# levels against a recorded no-contact image; on quieter images (a simulator that adds less or none, a quiet
# camera) the thresholds fell with the noise and the mask took in the imprint's faint halo, and the estimates
# read worse: validation's scenes 0.52 cm at noise 2 and 0.54 without noise, against 0.32 at 7 (real_sensors.md).
# Every image of the pipeline's sets has noise of 6.6 grey levels or more, so none of them is changed.
MIN_NOISE = 5.0


def smoothed_difference_noise(smooth: np.ndarray, noise: float, sigma: float) -> float:
    """The noise's standard deviation (per channel) in D smoothed by a Gaussian of ``sigma`` pixels.

    smooth: that smoothed D (H, W, 3); noise: raw D's per-pixel noise (``difference_to_noise``). White noise:
    ``smoothed_noise(noise, sigma)``. Noise blurred before it reached D (JPEG, defocus), which that formula
    puts 2 to 10 times too low: the smoothed D's own ``far_residual_noise`` (see CORRELATED_RATIO above).
    """
    white = smoothed_noise(noise, sigma)
    if far_residual_noise(smooth, _pixels(CORRELATED_TEST * sigma)) <= CORRELATED_RATIO * white:
        return white
    return far_residual_noise(smooth, _pixels(CORRELATED_LEVEL * sigma))


def _pixels(distance: float) -> int:
    return max(1, int(round(distance)))


def far_residual_noise(smooth: np.ndarray, distance: int) -> float:
    """Smoothed D (H, W, 3) -> the standard deviation of its noise, from each pixel's residual against the mean
    of the four pixels ``distance`` away (rows and columns), on every second row and column: for noise whose
    correlation has died out at that distance the residual's variance is 1.25 times the noise's; the median
    absolute residual (times 1.4826) keeps the imprint's edges out, as ``difference_to_noise`` does."""
    d = int(distance)
    c = smooth[d:-d:2, d:-d:2]
    rows = smooth[: -2 * d : 2, d:-d:2] + smooth[2 * d :: 2, d:-d:2]
    around = rows + (smooth[d:-d:2, : -2 * d : 2] + smooth[d:-d:2, 2 * d :: 2])
    return _median_to_noise(np.median(np.abs(c - 0.25 * around)))


# A seeded region under this share of the largest one's area is not part of the contact: dust or a fleck that
# settled on the gel after its no-contact image was recorded reads as a small dark blob, which the convex hull
# below would join to the press, spreading the mask across the gel. A press's own regions are one blob, or a few
# of like size (two edges of a box); four dark specks of 2.5 px on validation's images took its mean positional
# error from 0.32 to 0.52 cm (offaxis 0.55 to 0.93) when kept (docs/contact_patch.md).
SPECK_FRACTION = 0.05


def difference_to_mask(smooth: np.ndarray, noise: float, model: PatchModel) -> np.ndarray:
    """Smoothed D (H, W, 3), noise std of raw D -> contact mask (H, W) bool.

    Hysteresis: connected regions of ``|D| > grow_level * s`` kept when they contain a pixel over
    ``seed_level * s`` and at least ``min_area`` pixels, with ``s`` the smoothed noise's std (per channel,
    ``smoothed_difference_noise``, at least that of ``MIN_NOISE``; the magnitude of 3-channel noise alone is
    about 1.6 s), and at least ``SPECK_FRACTION`` of the largest such region's. Then holes are filled (a flat face pressed square leaves a faint centre) and the outline is
    closed morphologically.
    """
    s = max(smoothed_difference_noise(smooth, noise, model.mask_sigma), smoothed_noise(MIN_NOISE, model.mask_sigma))
    magnitude = _magnitude(smooth)
    low = (magnitude > model.grow_level * s).astype(np.uint8)
    # (the regions only: OpenCV's statistics cost three times the labelling, and only seeded regions' areas count)
    count, labels = cv2.connectedComponents(low, connectivity=8)
    if count <= 1:
        return np.zeros(magnitude.shape, dtype=bool)
    # The regions whose peak exceeds the seed level: those with a pixel above it (NaN pixels are in no region).
    seeded = np.flatnonzero(np.bincount(labels[magnitude > model.seed_level * s], minlength=count)[1:]) + 1
    if len(seeded) <= 4:  # usually one or two: comparisons beat counting every label's pixels
        regions = [labels == label for label in seeded]
        areas = [np.count_nonzero(region) for region in regions]
        smallest = max(model.min_area, SPECK_FRACTION * max(areas, default=0))
        mask = np.zeros(labels.shape, dtype=np.uint8)
        for region, area in zip(regions, areas):
            if area >= smallest:
                mask |= region
    else:
        areas = np.bincount(labels.ravel(), minlength=count)
        keep = np.zeros(count, dtype=bool)
        keep[seeded] = areas[seeded] >= max(model.min_area, SPECK_FRACTION * areas[seeded].max())
        mask = keep.view(np.uint8)[labels]
    if not mask.any():
        return mask.astype(bool)
    if model.convex:
        mask = _convex_hull(mask).astype(np.uint8)
    else:
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
        mask = _fill_holes(mask.astype(bool)).astype(np.uint8)
    if model.erode > 0:
        size = 2 * int(model.erode) + 1
        mask = cv2.erode(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    return mask.astype(bool)


def _magnitude(smooth: np.ndarray) -> np.ndarray:
    """|D| (H, W) float64 of a D (H, W, 3): ``np.sqrt(np.sum(smooth.astype(np.float64) ** 2, axis=-1))``.

    Written out per channel plane, which is three times faster than NumPy's reduction over a length-3 axis, in
    the order that reduction adds a fresh contiguous array's channels, ``(c0 + c1) + c2`` (the test checks it).
    """
    c0, c1, c2 = (smooth[..., c].astype(np.float64) for c in range(3))
    c0 *= c0
    c0 += c1 * c1
    c0 += c2 * c2
    return np.sqrt(c0, out=c0)


def _convex_hull(mask: np.ndarray) -> np.ndarray:
    """The filled convex hull of a mask's pixels (H, W) bool.

    The hull of the regions' outer boundary pixels is the hull of all their pixels (a hull's vertices are
    extreme points, which lie on a boundary), and there are far fewer of them to pass.
    """
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    hull = cv2.convexHull(np.concatenate(contours))
    out = np.zeros(mask.shape, dtype=np.uint8)
    cv2.fillConvexPoly(out, hull, 1)
    return out.astype(bool) | mask.astype(bool)


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    """Fill the background components that do not touch the image border."""
    _, labels = cv2.connectedComponents((~mask).astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    outside = np.isin(labels, border) & ~mask
    return ~outside


# --- colour to normal ------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def _monomial_exponents(n_inputs: int, degree: int) -> np.ndarray:
    """All exponent vectors of total degree <= degree: (F, n_inputs) int, the constant first."""
    out = []
    for d in range(degree + 1):
        for combo in itertools.combinations_with_replacement(range(n_inputs), d):
            out.append(np.bincount(np.array(combo, dtype=int), minlength=n_inputs))
    exps = np.array(out)
    exps.setflags(write=False)
    return exps


@functools.lru_cache(maxsize=8)
def _monomial_plan(n_inputs: int, degree: int) -> tuple[tuple[int, int, int], ...]:
    """How ``regression_features`` makes each monomial of degree >= 2 from two earlier ones: (k, a, b) triples
    meaning feature k = feature a * feature b, in feature order (so a and b are always ready).

    The textbook evaluation multiplies 1 by ``x_i ** e_i`` for the monomial's variables in index order, with
    ``x_i ** p = x_i ** (p - 1) * x_i``. So ``x_i ** p`` (one variable) is feature ``x_i ** (p - 1)`` times
    feature ``x_i``, and a monomial of several variables is the feature without its last variable times that
    variable's power: the same two numbers multiplied, hence the same bits, with one product per feature.
    """
    exps = _monomial_exponents(n_inputs, degree)
    index = {tuple(e): k for k, e in enumerate(exps)}
    plan = []
    for k, e in enumerate(exps):
        if e.sum() <= 1:
            continue  # the constant 1 and the inputs themselves (1 * x_i is x_i)
        nonzero = np.flatnonzero(e)
        last = nonzero[-1]
        head, tail = e.copy(), np.zeros_like(e)
        if len(nonzero) == 1:
            head[last] -= 1
            tail[last] = 1
        else:
            head[last] = 0
            tail[last] = e[last]
        plan.append((k, index[tuple(head)], index[tuple(tail)]))
    return tuple(plan)


# Blocks per pass of the feature loops: the (F, chunk) float64 buffer (~0.9 MB for F = 56) stays in cache.
_FEATURE_CHUNK = 2048


def _feature_chunks(colour: np.ndarray, rays: np.ndarray, degree: int, colour_scale: float):
    """Yield (start, features (F, m) float64) for consecutive chunks of at most ``_FEATURE_CHUNK`` of the n
    inputs: feature rows in ``_monomial_exponents`` order, one product per feature (``_monomial_plan``).
    The buffer is reused: consume each chunk before asking for the next."""
    colour = np.asarray(colour, np.float64)
    n, n_colour = colour.shape
    n_inputs = n_colour + 2
    n_features = len(_monomial_exponents(n_inputs, degree))
    plan = _monomial_plan(n_inputs, degree)
    x = np.empty((n_inputs, n))
    np.divide(colour.T, colour_scale, out=x[:n_colour])
    x[n_colour:] = 2.0 * np.asarray(rays)[:, 1:3].T
    buf = np.empty((n_features, min(_FEATURE_CHUNK, n)))
    for start in range(0, n, _FEATURE_CHUNK):
        part = buf[:, : min(_FEATURE_CHUNK, n - start)]
        part[0] = 1.0
        if degree >= 1:
            part[1 : n_inputs + 1] = x[:, start : start + part.shape[1]]
        for k, a, b in plan:
            np.multiply(part[a], part[b], out=part[k])
        yield start, part


def regression_features(colour: np.ndarray, rays: np.ndarray, degree: int, colour_scale: float) -> np.ndarray:
    """Smoothed D values (n, 3) grey levels and their rays (n, 3) -> polynomial features (n, F) float64.

    Inputs: D / colour_scale and the ray's (u, v) times 2 (about [-1, 1] over the image); features: all
    their monomials of total degree <= ``degree``, in ``_monomial_exponents`` order. The calibration's
    design matrix; ``regression_predict`` evaluates the fitted model without building it.
    """
    n = len(colour)
    feats = np.empty((n, len(_monomial_exponents(np.shape(colour)[1] + 2, degree))))
    for start, part in _feature_chunks(colour, rays, degree, colour_scale):
        feats[start : start + part.shape[1]] = part.T
    return feats


def regression_predict(colour: np.ndarray, rays: np.ndarray, degree: int, colour_scale: float,
                       coefficients: np.ndarray) -> np.ndarray:
    """The fitted regression at n inputs: ``regression_features(...) @ coefficients`` (n, m) float64, for
    coefficients (F, m).

    Multiplied chunk by chunk as the features are made, so the (n, F) matrix is never transposed into
    place (that copy took a third of the normals' time); equal to the product of the whole matrix up to
    the rounding of the sums (the test checks it against that product).
    """
    coefficients = np.asarray(coefficients, dtype=np.float64)
    out = np.empty((coefficients.shape[1], len(colour)))
    for start, part in _feature_chunks(colour, rays, degree, colour_scale):
        np.matmul(coefficients.T, part, out=out[:, start : start + part.shape[1]])
    return out.T


def lateral_to_normals(lateral: np.ndarray) -> np.ndarray:
    """(n, 2) predicted (n_y, n_z) -> (n, 3) unit normals facing the camera (n_x < 0).

    Lateral parts longer than ``_MAX_LATERAL`` are scaled down to it. (Written per column: a sum of two
    squares is the same number in either order, so this is ``np.linalg.norm`` / ``np.sum`` over the pair.)
    """
    lat = np.asarray(lateral, dtype=np.float64)
    y, z = lat[:, 0], lat[:, 1]
    r = np.sqrt(y * y + z * z)
    over = r > _MAX_LATERAL
    shrink = _MAX_LATERAL / np.maximum(r, 1e-12)
    out = np.empty((len(lat), 3))
    out[:, 1] = np.where(over, y * shrink, y)
    out[:, 2] = np.where(over, z * shrink, z)
    y, z = out[:, 1], out[:, 2]
    out[:, 0] = -np.sqrt(1.0 - (y * y + z * z))
    return out


# --- the region the per-pixel work is done on -------------------------------------------------------------
#
# A press covers part of the image; off its mask the normals are the gel's and the depth is zero, known
# without computing. The per-pixel steps below therefore run on a rectangle ("box": a (rows, columns) pair of
# slices) around the mask, and give, pixel for pixel, the numbers the whole-image computation gives:
# - the normals: the block regression only ever ran on blocks in the mask, and the 2x upsampling still runs
#   on the whole image (cheap at block resolution), so each pixel's interpolated value is unchanged; the box
#   only limits the float64 normalisation and the log-gradients, which are per pixel;
# - the depth: the least-squares system has one unknown per grid cell in the mask and one equation per pair
#   of neighbouring cells with at least one of them in the mask, in row-major order. With the box holding
#   the mask's cells and their neighbours (a margin of two cells), the gradients of every cell an equation
#   reads are computed from the same pixels as before, the other cells' gradients are read by no equation,
#   and the system is built on the whole (coarse) grid as before: the same matrix, right-hand side and
#   solution. The upsampling of the cells' depths runs on the whole image;
# - the contact: only pixels in the mask are weighed (see image_to_patch for the band), and the box keeps
#   them in row-major order, so the same weights and sums.
# OpenCV's resampling is only ever called on the whole image, never on a box, so its results cannot depend
# on where the box lies (its SIMD and scalar paths split a row by position).


def _work_box(mask: np.ndarray, k: int) -> tuple[slice, slice]:
    """The box to work on for a mask (H, W) and the depth grid's step k (pixels): the mask's bounding box grown
    by two grid cells (``2 k`` pixels), widened to whole cells of the grid and of the normals' 2 x 2 blocks and
    clipped to the image. The whole image when the image is not a whole number of cells (nothing is cropped).
    """
    h, w = mask.shape
    align = k * 2 // math.gcd(k, 2)
    if h % align or w % align:
        return slice(0, h), slice(0, w)
    x, y, bw, bh = cv2.boundingRect(np.ascontiguousarray(mask, dtype=bool).view(np.uint8))
    margin = 2 * k
    r0, r1 = max((y - margin) // align * align, 0), min(-(-(y + bh + margin) // align) * align, h)
    c0, c1 = max((x - margin) // align * align, 0), min(-(-(x + bw + margin) // align) * align, w)
    return slice(r0, r1), slice(c0, c1)


def _whole_box(shape: tuple[int, ...]) -> tuple[slice, slice]:
    """The box of a whole (H, W, ...) array: the whole-image computation."""
    return slice(0, shape[0]), slice(0, shape[1])


def _box_normals(smooth: np.ndarray, mask: np.ndarray, model: PatchModel, box) -> tuple[np.ndarray, np.ndarray]:
    """``difference_to_normals`` on a box -> normals (3, h, w) float64 (component planes of the box) and the
    direct press depth (H, W) float64 of the whole image (metres; zero off the mask).
    """
    k = 2
    gel_normals = _geometry_planes()[1]
    block_rays, block_gel = _block_geometry(k)
    block_mask = _block_mean(mask.astype(np.float32), k) > 0.0
    block_normals = block_gel.copy()
    block_depth = np.zeros(block_mask.shape)
    if block_mask.any():
        colour = _block_mean(smooth, k)[block_mask]
        pred = regression_predict(colour, block_rays[block_mask], model.degree, model.colour_scale, model.coefficients)
        block_normals[block_mask] = lateral_to_normals(pred[:, :2])
        block_depth[block_mask] = np.clip(pred[:, 2] * 1e-3, 0.0, None)
    up = cv2.resize(block_normals.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
    depth = np.where(mask, cv2.resize(block_depth.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR), 0.0)
    # Normalise in float64, per component plane: |up| is sqrt((x^2 + y^2) + z^2), the order in which NumPy's
    # norm over the last axis of the whole (H, W, 3) array added them (the test checks it).
    u = [up[box + (c,)].astype(np.float64) for c in range(3)]
    norm = u[0] * u[0]
    norm += u[1] * u[1]
    norm += u[2] * u[2]
    np.sqrt(norm, out=norm)
    outside = ~np.asarray(mask[box], dtype=bool)
    planes = np.empty((3,) + norm.shape)
    for c in range(3):
        np.divide(u[c], norm, out=planes[c])
        np.copyto(planes[c], gel_normals[(c,) + box], where=outside)
    return planes, depth


def difference_to_normals(smooth: np.ndarray, mask: np.ndarray, model: PatchModel) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed D (H, W, 3), mask (H, W) -> unit normals (H, W, 3) of the visible surface, and the
    colour's direct press-depth estimate (H, W) metres.

    Inside the mask: the regression, evaluated on 2 x 2 pixel blocks (the smoothed difference varies
    little over two pixels, and this quarters the cost) and interpolated back. Outside: the gel's own
    normal and zero depth.
    """
    box = _work_box(mask, 2)
    planes, depth = _box_normals(smooth, mask, model, box)
    normals = np.array(_camera_geometry()[2])
    normals[box] = np.moveaxis(planes, 0, -1)
    return normals, depth


# --- normals to depth -------------------------------------------------------------------------------------


def _log_gradients(planes: np.ndarray, box) -> tuple[np.ndarray, np.ndarray]:
    """``normals_to_log_gradients`` of normals given as component planes (3, h, w) of a box -> (h, w) each.

    ``n . r`` is added as ``(n_x r_x + n_y r_y) + n_z r_z``, the order of NumPy's sum over the last axis of
    the whole (H, W, 3) product (the test checks it).
    """
    rays = _geometry_planes()[0]
    n_dot_r = planes[0] * rays[(0,) + box]
    n_dot_r += planes[1] * rays[(1,) + box]
    n_dot_r += planes[2] * rays[(2,) + box]
    np.minimum(n_dot_r, -1e-3, out=n_dot_r)  # the surface faces the camera
    g_u = -planes[1] / n_dot_r
    g_v = -planes[2] / n_dot_r
    g_u *= -1.0 / _FOCAL
    g_v *= -1.0 / _FOCAL
    return g_u, g_v


def normals_to_log_gradients(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (H, W, 3) -> d log t / d column, d log t / d row (H, W) each, per pixel.

    From ``d log t / du = -n_y / (n . r)``, ``d log t / dv = -n_z / (n . r)`` and the pixel grid:
    u falls by 1/f per column and v by 1/f per row (f the focal length in pixels).
    """
    normals = np.asarray(normals)
    return _log_gradients(np.moveaxis(normals, -1, 0), _whole_box(normals.shape))


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    """Mean over k x k pixel blocks of an (H, W) or (H, W, c<=4) array (OpenCV's area resampling is
    exactly that for an integer factor, and far faster than NumPy's reductions over small axes)."""
    h, w = a.shape[0] // k, a.shape[1] // k
    dtype = np.float64 if a.dtype == np.float64 else np.float32
    return cv2.resize(np.ascontiguousarray(a[: h * k, : w * k], dtype=dtype), (w, h), interpolation=cv2.INTER_AREA)


# Weight of the pull of each cell's log t toward the prior's (normals_to_depth): weak beside the gradients'.
_PRIOR_WEIGHT = 1e-3


def _solve_normal_equations(ends: np.ndarray, rhs: np.ndarray, prior_log: np.ndarray) -> np.ndarray:
    """The least-squares solution x (n,) of the depth integration: equations ``x_b - x_a = rhs`` (E,) for the
    rows (a, b) of ``ends`` (E, 2), an index < 0 marking an end outside the mask (its known value already in
    ``rhs``), and ``w * x_i = w * prior_log_i`` (n,) for every unknown, ``w = _PRIOR_WEIGHT``.

    The normal equations ``A^T A x = A^T b`` are a grid graph's Laplacian plus ``w**2`` on the diagonal:
    symmetric positive definite, and banded, since in the cells' row-major order two neighbours are at most
    a row of cells apart. So they are built in LAPACK's banded form directly and solved by a banded
    Cholesky factorisation (``solveh_banded``), three times faster than a general sparse LU here; the
    matrix is the same, the solution equal to a sparse solver's up to rounding (the test checks it).
    """
    n, weight = len(prior_log), _PRIOR_WEIGHT
    a, b = ends[:, 0], ends[:, 1]
    both = (a >= 0) & (b >= 0)
    bandwidth = int(np.max(b[both] - a[both], initial=0))
    ab = np.zeros((bandwidth + 1, n))
    # a, the left or upper cell, has the smaller index: entry (a, b) of the upper triangle is -1.
    ab[bandwidth - (b[both] - a[both]), b[both]] = -1.0
    present = ends[ends >= 0]
    ab[bandwidth] = np.bincount(present, minlength=n) + weight * weight
    Atb = (weight * weight) * prior_log
    Atb -= np.bincount(a[a >= 0], weights=rhs[a >= 0], minlength=n)
    Atb += np.bincount(b[b >= 0], weights=rhs[b >= 0], minlength=n)
    return scipy.linalg.solveh_banded(ab, Atb, check_finite=False)


def _box_depth(g_col: np.ndarray, g_row: np.ndarray, mask: np.ndarray, k: int, prior: np.ndarray | None,
               box) -> np.ndarray:
    """``normals_to_depth`` from the log-gradients (h, w) of a box holding the mask's cells and their neighbours
    (``_work_box``) -> press depth (H, W) float32 m. Needs a mask with a pixel in it."""
    depth = np.zeros(mask.shape, dtype=np.float32)
    # The cells' mean gradients, from whole-image arrays so that OpenCV sees the same array it always did
    # in every cell an equation reads; cells off the box get 0, and no equation reads them.
    grad = np.zeros(mask.shape)
    grad[box] = g_col
    gc = _block_mean(grad, k) * k
    grad[box] = g_row
    gr = _block_mean(grad, k) * k
    # (a cell's mean of 0s and 1s is > 0 exactly when one is 1, in float32 as in float64)
    coarse_mask = _block_mean(mask.astype(np.float32), k) > 0.0
    log_gel, gel_t = _coarse_gel(k)
    h, w = coarse_mask.shape
    index = -np.ones((h, w), dtype=np.int64)
    index[coarse_mask] = np.arange(int(coarse_mask.sum()))
    ends, rhs = [], []
    for axis, g in ((1, gc), (0, gr)):
        a_idx = index[:, :-1] if axis == 1 else index[:-1, :]
        b_idx = index[:, 1:] if axis == 1 else index[1:, :]
        step = 0.5 * ((g[:, :-1] + g[:, 1:]) if axis == 1 else (g[:-1, :] + g[1:, :]))
        la = log_gel[:, :-1] if axis == 1 else log_gel[:-1, :]
        lb = log_gel[:, 1:] if axis == 1 else log_gel[1:, :]
        use = (a_idx >= 0) | (b_idx >= 0)
        a_i, b_i, st, la_, lb_ = a_idx[use], b_idx[use], step[use], la[use], lb[use]
        # L_b - L_a = step; a known (outside) end moves to the right-hand side.
        r = st.copy()
        r[a_i < 0] += la_[a_i < 0]
        r[b_i < 0] -= lb_[b_i < 0]
        ends.append(np.stack([a_i, b_i], axis=1))
        rhs.append(r)
    t_prior = gel_t - (0.0 if prior is None else _block_mean(prior, k))
    log_prior = np.log(np.maximum(t_prior, 1e-3))[coarse_mask]
    coarse_log = log_gel.copy()
    coarse_log[coarse_mask] = _solve_normal_equations(np.concatenate(ends), np.concatenate(rhs), log_prior)
    # A gel distance of a kilometre is no press, and its depth still turns every pixel it is interpolated
    # into negative (a bilinear weight is at least 1/(2k)), hence 0, as any larger one would; the cap keeps
    # it finite in float32, where a larger one may be infinite and spread NaN through the interpolation.
    coarse_depth = gel_t - np.exp(np.minimum(coarse_log, np.log(1e3)))
    full = cv2.resize(coarse_depth.astype(np.float32), (w * k, h * k), interpolation=cv2.INTER_LINEAR)
    depth[: h * k, : w * k] = full
    depth[~mask] = 0.0
    return np.maximum(depth, 0.0, out=depth)


def normals_to_depth(normals: np.ndarray, mask: np.ndarray, grid_step: int = 4, prior: np.ndarray | None = None) -> np.ndarray:
    """Unit normals (H, W, 3) of the visible surface, contact mask (H, W) -> press depth (H, W) float32 m.

    Integrates ``log t`` by least squares on a grid ``grid_step`` times coarser: one equation per pair of
    neighbouring cells (the difference of ``log t`` equals the mean of their gradients), with ``log t``
    held at the gel's value in cells outside the mask. A weak pull toward ``prior`` (H, W) press depths
    (the colour's direct estimate; zero when None) fixes the one free constant when the mask covers the
    whole image and leaves no edge to hold; otherwise the mask's edge dominates it. Depth = gel distance
    - t, clipped at 0, 0 off the mask. Only the normals near the mask are read (see ``_work_box``).
    """
    if not mask.any():
        return np.zeros(mask.shape, dtype=np.float32)
    k = int(grid_step)
    box = _work_box(mask, k)
    planes = np.moveaxis(np.asarray(normals)[box], -1, 0)
    return _box_depth(*_log_gradients(planes, box), mask, k, prior, box)


def depth_to_points(depth: np.ndarray) -> np.ndarray:
    """Press depth (H, W) m -> (H, W, 3) points in the sensor frame: ``camera + (t_gel - depth) * ray``."""
    rays, t_gel, _ = _camera_geometry()
    return CAMERA_POSITION + (t_gel - depth)[..., None] * rays


def pixels_to_points(depth: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``depth_to_points(depth)[rows, cols]`` (N, 3), computed at those N pixels only (same numbers)."""
    rays, t_gel, _ = _camera_geometry()
    return CAMERA_POSITION + (t_gel[rows, cols] - depth[rows, cols])[..., None] * rays[rows, cols]


def _box_contact(depth: np.ndarray, planes: np.ndarray | None, top_band: float, box):
    """``depth_to_contact`` with the normals given as component planes (3, h, w) of a box, which must hold
    every pixel the band can weigh: all pressed pixels when ``top_band <= 1`` (then the band's floor is
    >= 0 and a pixel of zero depth is never inside it); the whole image otherwise."""
    dmax = float(depth.max()) if depth.size else 0.0
    if not dmax > 0.0:
        return None, None
    floor = dmax * (1.0 - top_band)
    inner = depth[box]
    w = np.clip(inner - floor, 0.0, None).astype(np.float64)
    sel = w > 0
    if not sel.any():
        sel = inner >= dmax
        w = sel.astype(np.float64)
    w = w[sel] / w[sel].sum()
    rows, cols = np.nonzero(sel)
    point = w @ pixels_to_points(depth, rows + box[0].start, cols + box[1].start)
    normal = None
    if planes is not None:
        normal = w @ np.stack([p[sel] for p in planes], axis=1)
        normal /= np.linalg.norm(normal)
    return point, normal


def depth_to_contact(depth: np.ndarray, normals: np.ndarray | None, top_band: float = 0.1):
    """Press depth (H, W) m, optional normals (H, W, 3) -> contact point (3,) m, normal (3,) or None.

    The region pressed within ``top_band`` times the deepest press of the deepest, each pixel weighted by
    how far into that band it goes: the weighted mean of the surface points, and of the normals
    (normalised). Returns (None, None) when nothing is pressed.
    """
    planes = None if normals is None else np.moveaxis(np.asarray(normals), -1, 0)
    return _box_contact(depth, planes, top_band, _whole_box(depth.shape))


# --- the whole estimate ----------------------------------------------------------------------------------


def image_to_patch(image, no_contact, model: PatchModel | None = None) -> ContactPatch:
    """One tactile image and its sensor's no-contact image -> ContactPatch (sensor frame).

    image, no_contact: (320, 240, 3) uint8 RGB. model: a calibration (``calibrate`` / ``load_model``);
    None uses ``default_model()``. Raises InputError for bad images (see ``images_to_difference``).

    The steps of ``difference_to_normals``, ``normals_to_depth`` and ``depth_to_contact``, run on a box
    around the mask (``_work_box``): the same numbers, bit for bit, at a fraction of the cost.
    """
    model = default_model() if model is None else model
    diff = images_to_difference(image, no_contact)
    noise = _whole_level_noise(diff)
    smooth = smooth_difference(diff, model.mask_sigma)
    mask = difference_to_mask(smooth, noise, model)
    if not mask.any():
        return _no_contact(noise)
    if model.sigma != model.mask_sigma:  # else the same blur of the same image: reuse it
        smooth = smooth_difference(diff, model.sigma)
    k = int(model.grid_step)
    # A band wider than the deepest press (top_band > 1) would weigh pixels off the mask: whole image then.
    box = _work_box(mask, k) if model.top_band <= 1.0 else _whole_box(mask.shape)
    planes, direct = _box_normals(smooth, mask, model, box)
    depth = _box_depth(*_log_gradients(planes, box), mask, k, direct, box)
    point, normal = _box_contact(depth, planes, model.top_band, box)
    if point is None or not (np.all(np.isfinite(point)) and np.all(np.isfinite(normal))):
        return _no_contact(noise)
    return ContactPatch(True, mask, depth, point, normal, noise)


def _no_contact(noise: float) -> ContactPatch:
    return ContactPatch(False, np.zeros((H, W), dtype=bool), np.zeros((H, W), dtype=np.float32), None, None, noise)


# --- simulated presses of known shape --------------------------------------------------------------------


def tilted_sensor_pose(point, normal, roll: float, tilt_axis_angle: float, tilt: float, offset) -> np.ndarray:
    """A sensor touching ``point`` (3,) with outward ``normal`` (3,) off-centre and tilted -> T (4, 4).

    Start from the square placement (``sensor.sensor_poses_touching`` with zero depth, then the gel apex
    is on the point), shift the sensor by ``-offset`` (2,) metres along its own y and z so that the gel
    point ``offset`` from the apex comes over the surface point, then turn it by ``tilt`` radians about
    the point, about the axis perpendicular to the normal at angle ``tilt_axis_angle`` in the sensor's
    y-z plane. The press depth is set afterwards (``press_to_depth``).
    """
    p = np.asarray(point, dtype=np.float64)
    T = sensor.sensor_poses_touching(p, np.asarray(normal, dtype=np.float64), roll, 0.0)
    dy, dz = np.asarray(offset, dtype=np.float64)
    T = T @ make_pose(np.eye(3), [0.0, -dy, -dz])
    axis = T[:3, :3] @ np.array([0.0, np.cos(tilt_axis_angle), np.sin(tilt_axis_angle)])
    Q = axis_angle_to_rotmat(axis, np.asarray(tilt))
    return make_pose(Q, p - Q @ p) @ T


def press_to_depth(renderer: DigitRenderer, mesh, T_object_sensor: np.ndarray, depth: float) -> np.ndarray | None:
    """Move the sensor along its axis so that the deepest press is ``depth`` metres -> T (4, 4) or None.

    Press depth is measured along the sensor's +x axis, so moving the sensor by s along +x deepens every
    pressed pixel by exactly s. A pose that does not touch at all is first moved until it does (within
    10 mm); None when that fails.
    """
    arrays = mesh_arrays(mesh)
    T = np.array(T_object_sensor, dtype=np.float64)
    strict = renderer.strict
    renderer.strict = False
    try:
        _, d = renderer.contact(arrays, invert_pose(T))
        for _ in range(10):
            if d.max() > 0:
                break
            T[:3, 3] += 0.001 * T[:3, 0]
            _, d = renderer.contact(arrays, invert_pose(T))
        if not d.max() > 0:
            return None
        T[:3, 3] += (depth - float(d.max())) * T[:3, 0]
    finally:
        renderer.strict = strict
    return T


@dataclass(frozen=True)
class CalibrationPress:
    """One simulated press: the shape, the sensor pose in its frame, and the deepest press (m)."""

    shape: sq.Superquadric
    T_object_sensor: np.ndarray
    depth: float


def shape_to_mesh(shape: sq.Superquadric):
    """The superquadric's mesh as the training set meshes it (1 mm edges, 0.05 rad turns)."""
    return sq.superquadric_mesh(shape, 0.001, 0.05)


def sample_presses(
    n: int,
    rng: np.random.Generator,
    renderer: DigitRenderer,
    presses_per_shape: int = 4,
    size_range=(0.005, 0.08),
    exponent_range=(0.1, 1.5),
    depth_range=(0.0005, 0.0025),
    max_tilt: float = float(np.deg2rad(25.0)),
    max_offset: float = 0.005,
) -> list[CalibrationPress]:
    """n random presses on random superquadrics, off-centre and tilted, grouped by shape.

    Each shape (semi-axes uniform in ``size_range`` m, exponents in ``exponent_range``: spheres,
    ellipsoids, boxes, edges, corners) takes ``presses_per_shape`` contacts, consecutive in the list.
    Contact points favour edges and corners as the training set does; offsets are uniform in a square of
    half-side ``max_offset`` (m), tilts uniform in [0, max_tilt] about a random axis; then the deepest
    press is set uniform in ``depth_range``. Poses whose object would enter the sensor body are redrawn.
    """
    out: list[CalibrationPress] = []
    strict = renderer.strict
    while len(out) < n:
        shape = sq.random_superquadric(rng, size_range, exponent_range)
        mesh = shape_to_mesh(shape)
        arrays = mesh_arrays(mesh)
        count = min(presses_per_shape, n - len(out))
        points, normals, _ = sq.sample_surface_contacts(shape, mesh, 4 * count, rng, 0.3, 0.1, 0.008)
        kept = 0
        for p, nrm in zip(points, normals):
            if kept == count:
                break
            T = tilted_sensor_pose(p, nrm, rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi),
                                   rng.uniform(0.0, max_tilt), rng.uniform(-max_offset, max_offset, 2))
            depth = float(rng.uniform(*depth_range))
            T = press_to_depth(renderer, arrays, T, depth)
            if T is None:
                continue
            renderer.strict = True
            try:
                renderer.contact(arrays, invert_pose(T))
            except InputError:
                continue
            finally:
                renderer.strict = strict
            out.append(CalibrationPress(shape, T, depth))
            kept += 1
    return out


def true_normals(shape: sq.Superquadric, T_object_sensor: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """The visible surface's unit normals (H, W, 3), sensor frame, from a press's true depth (H, W) m.

    Pressed pixels: the shape's analytic outward normal at the surface point the depth gives. Others:
    the gel's normal.
    """
    _, _, gel_normals = _camera_geometry()
    out = np.array(gel_normals, dtype=np.float64)
    pressed = depth > 0
    if pressed.any():
        T = np.asarray(T_object_sensor, dtype=np.float64)
        p_sensor = depth_to_points(depth)[pressed]
        p_object = p_sensor @ T[:3, :3].T + T[:3, 3]
        out[pressed] = sq.surface_normals(shape, p_object) @ T[:3, :3]
    return out


def render_presses(renderer: DigitRenderer, presses: list[CalibrationPress], seed: int = 0):
    """Render presses -> images (n, H, W, 3) uint8, depths (n, H, W) float32 m, normals (n, H, W, 3) float32.

    Consecutive presses on the same shape share one mesh. Image i gets noise seed ``seed + i``.
    """
    n = len(presses)
    images = np.empty((n, H, W, 3), dtype=np.uint8)
    depths = np.empty((n, H, W), dtype=np.float32)
    normals = np.empty((n, H, W, 3), dtype=np.float32)
    arrays, shape = None, None
    for i, press in enumerate(presses):
        if press.shape is not shape:
            shape, arrays = press.shape, mesh_arrays(shape_to_mesh(press.shape))
        res = renderer.render(arrays, np.eye(4), press.T_object_sensor, seed=seed + i)
        images[i], depths[i] = res.image, res.depth
        normals[i] = true_normals(press.shape, press.T_object_sensor, res.depth)
    return images, depths, normals


def fit_model(
    images: np.ndarray,
    no_contact: np.ndarray,
    normals: np.ndarray,
    depths: np.ndarray,
    pixels_per_image: int = 3000,
    seed: int = 0,
    ridge: float = 1e-6,
    **settings,
) -> PatchModel:
    """Fit the colour-to-normal regression -> PatchModel.

    images (n, H, W, 3) uint8 and their sensor's no_contact (H, W, 3); normals (n, H, W, 3) the true
    visible-surface normals (``true_normals``); depths (n, H, W) the true press depths, metres. Training pixels: up to ``pixels_per_image`` random pixels
    per image inside the mask this model's own thresholds find (so the regression also learns the gel's
    normal where the mask overshoots the true imprint). settings: PatchModel fields other than
    coefficients. Ridge regularisation ``ridge`` (relative to the features' scale) keeps rare colours
    from blowing up the polynomial.
    """
    rng = np.random.default_rng(seed)
    probe = PatchModel(np.zeros((1, 3)), **settings)
    rays = _camera_geometry()[0]
    X, Y = [], []
    for img, nrm, dep in zip(images, normals, depths):
        diff = images_to_difference(img, no_contact)
        mask = difference_to_mask(smooth_difference(diff, probe.mask_sigma), difference_to_noise(diff), probe)
        smooth = smooth_difference(diff, probe.sigma)
        idx = np.flatnonzero(mask)
        if len(idx) == 0:
            continue
        idx = rng.choice(idx, size=min(pixels_per_image, len(idx)), replace=False)
        r, c = np.unravel_index(idx, mask.shape)
        X.append(regression_features(smooth[r, c], rays[r, c], probe.degree, probe.colour_scale))
        Y.append(np.concatenate([nrm[r, c, 1:3], 1e3 * dep[r, c, None]], axis=1))
    if not X:
        raise DataError("no calibration image showed a contact: nothing to fit")
    X, Y = np.concatenate(X), np.concatenate(Y)
    A = X.T @ X
    A[np.diag_indices_from(A)] += ridge * np.trace(A) / len(A)
    coefficients = np.linalg.solve(A, X.T @ Y)
    return PatchModel(coefficients, **settings)


def calibration_renderer(render_config: Mapping | None = None, **overrides) -> DigitRenderer:
    """The renderer calibration uses: the DIGIT model of ``render_config`` (the ``render`` config section;
    None: the default config's) over a flat mid-grey background, so that no difference clips."""
    grey = np.full((H, W, 3), 128, dtype=np.uint8)
    if render_config is None:
        return DigitRenderer.from_default_config(grey, **overrides)
    return DigitRenderer.from_config(render_config, grey, **overrides)


def calibration_set(n_presses: int, seed: int, renderer: DigitRenderer | None = None):
    """Simulated presses to calibrate on -> images (n, H, W, 3) uint8, depths (n, H, W) float32 m, normals
    (n, H, W, 3) float32 (``render_presses``), and the renderer's no-contact image (H, W, 3) uint8.

    ``sample_presses`` with its defaults; deterministic for a given seed and renderer (default
    ``calibration_renderer()``).
    """
    renderer = calibration_renderer() if renderer is None else renderer
    rng = np.random.default_rng(seed)
    presses = sample_presses(n_presses, rng, renderer)
    images, depths, normals = render_presses(renderer, presses, seed=int(rng.integers(2**31)))
    no_contact = renderer.no_contact(seed=int(rng.integers(2**31)))
    return images, depths, normals, no_contact


def calibrate(n_presses: int, seed: int, renderer: DigitRenderer | None = None, **settings) -> PatchModel:
    """Calibrate from simulated presses (``calibration_set``, then ``fit_model`` with ``settings``) -> PatchModel."""
    images, depths, normals, no_contact = calibration_set(n_presses, seed, renderer)
    return fit_model(images, no_contact, normals, depths, seed=seed, **settings)


@functools.lru_cache(maxsize=1)
def default_model() -> PatchModel:
    """``calibrate`` as the default config's ``patch`` section says (what stage calibrate_patch makes),
    computed once per process."""
    cfg = default_section("patch")
    return calibrate(int(cfg["n_presses"]), int(cfg["seed"]))


# --- saving ----------------------------------------------------------------------------------------------


def save_model(model: PatchModel, path) -> Path:
    """Write a PatchModel to an .npz file -> its path."""
    path = Path(path)
    fields = {k: getattr(model, k) for k in PatchModel.__dataclass_fields__}
    with open(path, "wb") as f:
        np.savez(f, format=np.array(_MODEL_FORMAT), **{k: np.asarray(v) for k, v in fields.items()})
    return path


def load_model(path) -> PatchModel:
    """Read a PatchModel written by ``save_model``. Raises DataError for a missing or foreign file."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "format" not in z or str(z["format"]) != _MODEL_FORMAT:
                raise DataError(f"{path}: not a contact-patch calibration ({_MODEL_FORMAT})")
            kwargs = {}
            for name, spec in PatchModel.__dataclass_fields__.items():
                value = z[name]
                # scalar settings come back as 0-d arrays: cast them to the field's own type
                kwargs[name] = np.array(value, dtype=np.float64) if name == "coefficients" else type(spec.default)(value)
            return PatchModel(**kwargs)
    except (OSError, ValueError, KeyError) as exc:
        raise DataError(f"{path}: cannot read a contact-patch calibration ({exc})") from exc
