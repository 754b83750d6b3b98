"""The contact patch of one tactile image: where the object presses, how deep, its contact point and normal.

Input: one DIGIT image (320, 240, 3) uint8 RGB and the same sensor's no-contact image. Everything is
computed from their difference, so the unit's own background (its vignetting, its LEDs' tint) cancels;
the simulator's background is never needed.

The method is GelSight-style photometric stereo, calibrated on simulated presses of known shape:

1. Difference image ``D = image - no_contact`` (float, RGB). The per-pixel noise level is estimated from
   the image itself (the median absolute Laplacian residual), so thresholds adapt to the unit and to
   whether the no-contact image is noisy or clean.
2. Mask: hysteresis on the magnitude of the Gaussian-smoothed difference (seeds well above the smoothed
   noise, grown through pixels moderately above it, small blobs dropped), then its convex hull, eroded
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
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from tactile6d.core import sensor
from tactile6d.core.config import default_section
from tactile6d.core.errors import DataError, InputError
from tactile6d.core.geometry import axis_angle_to_rotmat, invert_pose, make_pose
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


def gel_distance() -> np.ndarray:
    """(320, 240) float64 metres: the camera-axis distance of the unpressed gel seen by each pixel."""
    return _camera_geometry()[1]


# --- input checks ------------------------------------------------------------------------------------


def check_image(image, name: str = "image") -> np.ndarray:
    """A tactile image -> (320, 240, 3) uint8 array. Raises InputError naming what is wrong."""
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise InputError(f"{name} has dtype {a.dtype}; a tactile image is uint8")
    if a.shape != IMAGE_SHAPE:
        raise InputError(f"{name} has shape {a.shape}; a DIGIT image is {IMAGE_SHAPE}: 320 rows x 240 columns x RGB")
    return a


def images_to_difference(image, no_contact) -> np.ndarray:
    """image, no_contact: (320, 240, 3) uint8 RGB of the same sensor -> D (320, 240, 3) float32 grey levels.

    Raises InputError for a wrong shape or dtype, or when more than half of the image's pixels are
    saturated (0 or 255 in a channel where the no-contact image is not), which leaves no shading to read.
    """
    img = check_image(image, "image")
    bg = check_image(no_contact, "no-contact image")
    clipped = ((img == 0) & (bg != 0)) | ((img == 255) & (bg != 255))
    saturated = np.mean(np.any(clipped, axis=-1))
    if saturated > _MAX_SATURATED_FRACTION:
        raise InputError(f"{saturated:.0%} of the tactile image's pixels are saturated (0 or 255): no contact shading to read")
    return img.astype(np.float32) - bg.astype(np.float32)


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
    return float(1.4826 * np.median(np.abs(lap)) / np.sqrt(1.25))


def smooth_difference(diff: np.ndarray, sigma: float) -> np.ndarray:
    """D (H, W, 3) -> Gaussian-smoothed D, same shape, float32 (standard deviation ``sigma`` pixels)."""
    return cv2.GaussianBlur(np.asarray(diff, dtype=np.float32), (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def smoothed_noise(noise: float, sigma: float) -> float:
    """Standard deviation of white noise of std ``noise`` after a 2D Gaussian of ``sigma`` pixels."""
    return noise / (2.0 * np.sqrt(np.pi) * sigma)


def difference_to_mask(smooth: np.ndarray, noise: float, model: PatchModel) -> np.ndarray:
    """Smoothed D (H, W, 3), noise std of raw D -> contact mask (H, W) bool.

    Hysteresis: connected regions of ``|D| > grow_level * s`` kept when they contain a pixel over
    ``seed_level * s`` and at least ``min_area`` pixels, with ``s`` the smoothed noise's std (per channel;
    the magnitude of 3-channel noise alone is about 1.6 s). Then holes are filled (a flat face pressed
    square leaves a faint centre) and the outline is closed morphologically.
    """
    s = max(smoothed_noise(noise, model.mask_sigma), 0.05)
    magnitude = np.sqrt(np.sum(smooth.astype(np.float64) ** 2, axis=-1))
    low = (magnitude > model.grow_level * s).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(low, connectivity=8)
    if count <= 1:
        return np.zeros(magnitude.shape, dtype=bool)
    peak = np.zeros(count)
    np.maximum.at(peak, labels.ravel(), magnitude.ravel())
    keep = (peak > model.seed_level * s) & (stats[:, cv2.CC_STAT_AREA] >= model.min_area)
    keep[0] = False
    mask = keep[labels].astype(np.uint8)
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


def _convex_hull(mask: np.ndarray) -> np.ndarray:
    """The filled convex hull of a mask's pixels (H, W) bool."""
    pts = cv2.findNonZero(mask.astype(np.uint8))
    hull = cv2.convexHull(pts)
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


def regression_features(colour: np.ndarray, rays: np.ndarray, degree: int, colour_scale: float) -> np.ndarray:
    """Smoothed D values (n, 3) grey levels and their rays (n, 3) -> polynomial features (n, F) float64.

    Inputs: D / colour_scale and the ray's (u, v) times 2 (about [-1, 1] over the image); features: all
    their monomials of total degree <= ``degree``.
    """
    x = np.concatenate([np.asarray(colour, np.float64) / colour_scale, 2.0 * np.asarray(rays)[:, 1:3]], axis=1)
    exps = _monomial_exponents(x.shape[1], degree)
    powers = np.ones((x.shape[1], degree + 1, len(x)))
    for p in range(1, degree + 1):
        powers[:, p] = powers[:, p - 1] * x.T
    feats = np.ones((len(x), len(exps)))
    for k, e in enumerate(exps):
        for i in np.flatnonzero(e):
            feats[:, k] *= powers[i, e[i]]
    return feats


def lateral_to_normals(lateral: np.ndarray) -> np.ndarray:
    """(n, 2) predicted (n_y, n_z) -> (n, 3) unit normals facing the camera (n_x < 0)."""
    lat = np.asarray(lateral, dtype=np.float64)
    r = np.linalg.norm(lat, axis=1, keepdims=True)
    lat = np.where(r > _MAX_LATERAL, lat * (_MAX_LATERAL / np.maximum(r, 1e-12)), lat)
    nx = -np.sqrt(1.0 - np.sum(lat**2, axis=1))
    return np.concatenate([nx[:, None], lat], axis=1)


def difference_to_normals(smooth: np.ndarray, mask: np.ndarray, model: PatchModel) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed D (H, W, 3), mask (H, W) -> unit normals (H, W, 3) of the visible surface, and the
    colour's direct press-depth estimate (H, W) metres.

    Inside the mask: the regression, evaluated on 2 x 2 pixel blocks (the smoothed difference varies
    little over two pixels, and this quarters the cost) and interpolated back. Outside: the gel's own
    normal and zero depth.
    """
    k = 2
    _, _, gel_normals = _camera_geometry()
    block_rays, block_gel = _block_geometry(k)
    block_mask = _block_mean(mask.astype(np.float32), k) > 0.0
    block_normals = block_gel.copy()
    block_depth = np.zeros(block_mask.shape)
    if block_mask.any():
        colour = _block_mean(smooth, k)[block_mask]
        pred = regression_features(colour, block_rays[block_mask], model.degree, model.colour_scale) @ model.coefficients
        block_normals[block_mask] = lateral_to_normals(pred[:, :2])
        block_depth[block_mask] = np.clip(pred[:, 2] * 1e-3, 0.0, None)
    up = cv2.resize(block_normals.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR).astype(np.float64)
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    normals = np.where(mask[..., None], up, gel_normals)
    depth = np.where(mask, cv2.resize(block_depth.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR), 0.0)
    return normals, depth


# --- normals to depth -------------------------------------------------------------------------------------


def normals_to_log_gradients(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (H, W, 3) -> d log t / d column, d log t / d row (H, W) each, per pixel.

    From ``d log t / du = -n_y / (n . r)``, ``d log t / dv = -n_z / (n . r)`` and the pixel grid:
    u falls by 1/f per column and v by 1/f per row (f the focal length in pixels).
    """
    rays = _camera_geometry()[0]
    n_dot_r = np.sum(normals * rays, axis=-1)
    n_dot_r = np.minimum(n_dot_r, -1e-3)  # the surface faces the camera
    g_u = -normals[..., 1] / n_dot_r
    g_v = -normals[..., 2] / n_dot_r
    return g_u * (-1.0 / _FOCAL), g_v * (-1.0 / _FOCAL)


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    """Mean over k x k pixel blocks of an (H, W) or (H, W, c<=4) array (OpenCV's area resampling is
    exactly that for an integer factor, and far faster than NumPy's reductions over small axes)."""
    h, w = a.shape[0] // k, a.shape[1] // k
    dtype = np.float64 if a.dtype == np.float64 else np.float32
    return cv2.resize(np.ascontiguousarray(a[: h * k, : w * k], dtype=dtype), (w, h), interpolation=cv2.INTER_AREA)


def normals_to_depth(normals: np.ndarray, mask: np.ndarray, grid_step: int = 4, prior: np.ndarray | None = None) -> np.ndarray:
    """Unit normals (H, W, 3) of the visible surface, contact mask (H, W) -> press depth (H, W) float32 m.

    Integrates ``log t`` by least squares on a grid ``grid_step`` times coarser: one equation per pair of
    neighbouring cells (the difference of ``log t`` equals the mean of their gradients), with ``log t``
    held at the gel's value in cells outside the mask. A weak pull toward ``prior`` (H, W) press depths
    (the colour's direct estimate; zero when None) fixes the one free constant when the mask covers the
    whole image and leaves no edge to hold; otherwise the mask's edge dominates it. Depth = gel distance
    - t, clipped at 0, 0 off the mask.
    """
    _, t_gel, _ = _camera_geometry()
    depth = np.zeros(mask.shape, dtype=np.float32)
    if not mask.any():
        return depth
    k = int(grid_step)
    gc, gr = normals_to_log_gradients(normals)
    gc, gr = _block_mean(gc, k) * k, _block_mean(gr, k) * k
    coarse_mask = _block_mean(mask.astype(np.float64), k) > 0.0
    log_gel = np.log(_block_mean(t_gel, k))
    h, w = coarse_mask.shape
    index = -np.ones((h, w), dtype=np.int64)
    index[coarse_mask] = np.arange(int(coarse_mask.sum()))
    n = int(coarse_mask.sum())
    rows, cols, vals, rhs = [], [], [], []
    eq = 0
    for axis, g in ((1, gc), (0, gr)):
        a_idx = index[:, :-1] if axis == 1 else index[:-1, :]
        b_idx = index[:, 1:] if axis == 1 else index[1:, :]
        step = 0.5 * ((g[:, :-1] + g[:, 1:]) if axis == 1 else (g[:-1, :] + g[1:, :]))
        la = log_gel[:, :-1] if axis == 1 else log_gel[:-1, :]
        lb = log_gel[:, 1:] if axis == 1 else log_gel[1:, :]
        use = (a_idx >= 0) | (b_idx >= 0)
        a_i, b_i, st, la_, lb_ = a_idx[use], b_idx[use], step[use], la[use], lb[use]
        m = len(st)
        e = eq + np.arange(m)
        # L_b - L_a = step; a known (outside) end moves to the right-hand side.
        r = st.copy()
        r[a_i < 0] += la_[a_i < 0]
        r[b_i < 0] -= lb_[b_i < 0]
        rows.append(e[b_i >= 0]); cols.append(b_i[b_i >= 0]); vals.append(np.ones(int(np.sum(b_i >= 0))))
        rows.append(e[a_i >= 0]); cols.append(a_i[a_i >= 0]); vals.append(-np.ones(int(np.sum(a_i >= 0))))
        rhs.append(r)
        eq += m
    weight = 1e-3
    e = eq + np.arange(n)
    rows.append(e); cols.append(np.arange(n)); vals.append(np.full(n, weight))
    t_prior = np.exp(log_gel) - (0.0 if prior is None else _block_mean(prior, k))
    rhs.append(weight * np.log(np.maximum(t_prior, 1e-3))[coarse_mask])
    A = scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(eq + n, n))
    b = np.concatenate(rhs)
    L = scipy.sparse.linalg.spsolve((A.T @ A).tocsc(), A.T @ b)
    coarse_log = log_gel.copy()
    coarse_log[coarse_mask] = L
    coarse_depth = np.exp(log_gel) - np.exp(coarse_log)
    full = cv2.resize(coarse_depth.astype(np.float32), (w * k, h * k), interpolation=cv2.INTER_LINEAR)
    depth[: h * k, : w * k] = full
    depth[~mask] = 0.0
    return np.maximum(depth, 0.0, out=depth)


def depth_to_points(depth: np.ndarray) -> np.ndarray:
    """Press depth (H, W) m -> (H, W, 3) points in the sensor frame: ``camera + (t_gel - depth) * ray``."""
    rays, t_gel, _ = _camera_geometry()
    return CAMERA_POSITION + (t_gel - depth)[..., None] * rays


def depth_to_contact(depth: np.ndarray, normals: np.ndarray | None, top_band: float = 0.1):
    """Press depth (H, W) m, optional normals (H, W, 3) -> contact point (3,) m, normal (3,) or None.

    The region pressed within ``top_band`` times the deepest press of the deepest, each pixel weighted by
    how far into that band it goes: the weighted mean of the surface points, and of the normals
    (normalised). Returns (None, None) when nothing is pressed.
    """
    dmax = float(depth.max()) if depth.size else 0.0
    if not dmax > 0.0:
        return None, None
    floor = dmax * (1.0 - top_band)
    w = np.clip(depth - floor, 0.0, None).astype(np.float64)
    sel = w > 0
    if not sel.any():
        sel = depth >= dmax
        w = sel.astype(np.float64)
    w = w[sel] / w[sel].sum()
    point = w @ depth_to_points(depth)[sel]
    normal = None
    if normals is not None:
        normal = w @ normals[sel]
        normal /= np.linalg.norm(normal)
    return point, normal


# --- the whole estimate ----------------------------------------------------------------------------------


def image_to_patch(image, no_contact, model: PatchModel | None = None) -> ContactPatch:
    """One tactile image and its sensor's no-contact image -> ContactPatch (sensor frame).

    image, no_contact: (320, 240, 3) uint8 RGB. model: a calibration (``calibrate`` / ``load_model``);
    None uses ``default_model()``. Raises InputError for bad images (see ``images_to_difference``).
    """
    model = default_model() if model is None else model
    diff = images_to_difference(image, no_contact)
    noise = difference_to_noise(diff)
    mask = difference_to_mask(smooth_difference(diff, model.mask_sigma), noise, model)
    if not mask.any():
        return _no_contact(noise)
    normals, direct = difference_to_normals(smooth_difference(diff, model.sigma), mask, model)
    depth = normals_to_depth(normals, mask, model.grid_step, direct)
    point, normal = depth_to_contact(depth, normals, model.top_band)
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
