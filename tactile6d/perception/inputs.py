"""Checks of what a caller hands the estimator: sensor poses, tactile images and the sensors'
no-contact images (backgrounds).

Each check returns the input as the array the steps take, or raises InputError naming the first
problem, so that a robot's mistake is reported before any work is done. Beyond shapes and types, inputs
that are plausibly wrong are refused too: a grey image, an image whose red and blue look swapped against
its no-contact image (OpenCV's BGR order), sensors whose bodies overlap, touching sensors a metre apart
(poses in millimetres); one sensor only is accepted with a warning. They run once per
estimate and cost well under a millisecond per sensor. After the estimate, a best pose that presses deep into a
sensor is warned about: no pose fits the sensor poses as given (an inverted pose, a wrong frame).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import is_rotation, matrix_to_nearest_rotation
from tactile6d.core.sensor import (
    BOX_CENTER,
    BOX_HALF_EXTENTS,
    CONTACT_POINT,
    GEL_CENTER,
    GEL_HEIGHT,
    GEL_WIDTH,
    bodies_overlap,
    contact_points,
)
from tactile6d.data.hdf5 import TACTILE_IMAGE_SHAPE, sized_as_tactile, tactile_size_problem


# How far a sensor pose's rotation block may be from a rotation (largest entry of |R^T R - I|, and |det R - 1|)
# and still be taken for one: a matrix written with 4 decimals, or composed in float32 along a kinematic chain.
# Beyond ``EXACT_ROTATION`` it is replaced by the nearest rotation, which turns it by about this much at
# most (1e-3 rad, 0.06 deg: a fortieth of a hand's kinematic error).
ROTATION_TOLERANCE = 1e-3
EXACT_ROTATION = 1e-5


def check_sensor_poses(T_world_sensors) -> np.ndarray:
    """Sensor poses -> (L, 4, 4) float64, L >= 1; InputError naming the first bad one. A rotation block within
    ``ROTATION_TOLERANCE`` of a rotation is replaced by the nearest rotation (in the copy returned)."""
    T = np.asarray(T_world_sensors, dtype=np.float64)
    if T.ndim == 2 and T.shape == (4, 4):
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] < 1:
        raise InputError(f"sensor poses must be (L, 4, 4) with L >= 1, got shape {T.shape}")
    checked = T  # becomes a copy, never the caller's array, when a rotation block is replaced
    for i, pose in enumerate(T):
        if not np.all(np.isfinite(pose)):
            raise InputError(f"sensor pose {i} has NaN or infinite entries")
        R = pose[:3, :3]
        if not is_rotation(R, atol=ROTATION_TOLERANCE):
            deviation = float(np.abs(R.T @ R - np.eye(3)).max())
            raise InputError(f"sensor pose {i}: the upper-left 3x3 block is not a rotation matrix (R^T R is "
                             f"{deviation:.2g} off the identity, det R = {np.linalg.det(R):.4g}; up to "
                             f"{ROTATION_TOLERANCE:g} is taken for rounding)")
        if not is_rotation(R, atol=EXACT_ROTATION):
            if checked is T:
                checked = T.copy()
            checked[i, :3, :3] = matrix_to_nearest_rotation(R)
        if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0]):
            raise InputError(f"sensor pose {i}: the last row must be 0 0 0 1, got {pose[3].tolist()}")
    return checked


def check_images(images, n_sensors: int) -> np.ndarray:
    """L tactile images (an array or a sequence of arrays) -> (L, 320, 240, 3) uint8, one per sensor; an image
    at another size of the DIGIT's proportions is resized to it (``hdf5.sized_as_tactile``: an
    ``ImageSizeWarning``)."""
    if images is None:
        raise InputError("method 'ours' needs one tactile image per sensor, got none")
    if isinstance(images, np.ndarray) and images.ndim == 4:
        images = list(images)
    elif isinstance(images, np.ndarray) and images.ndim == 3 and n_sensors == 1:
        images = [images]  # one sensor's image, as one sensor's pose may be given as (4, 4)
    elif isinstance(images, np.ndarray):
        raise InputError(f"tactile images must be (L, 320, 240, 3), got shape {images.shape}")
    if len(images) != n_sensors:
        raise InputError(f"{len(images)} tactile images for {n_sensors} sensor poses")
    checked = []
    for i, image in enumerate(images):
        image = np.asarray(image)
        problem = tactile_size_problem(image.shape, f"image {i}")
        if problem is not None:
            raise InputError(problem)
        if image.dtype != np.uint8:
            raise InputError(f"image {i} has dtype {image.dtype}, tactile images must be uint8 (0-255) as the "
                             f"camera gives them{_uint8_hint(image.dtype)}")
        checked.append(sized_as_tactile(image, f"image {i}"))
    return np.stack(checked)


def _uint8_hint(dtype: np.dtype) -> str:
    """How to bring an image of ``dtype`` to uint8, for the error that refuses it."""
    if np.issubdtype(dtype, np.floating):
        return ": a float image in [0, 1] is (image * 255).round().astype(np.uint8)"
    if dtype == np.uint16:
        return ": a 16-bit image is (image >> 8).astype(np.uint8)"
    return ""


# --- no-contact images, one for all sensors or one per sensor -------------------------------------------


def check_backgrounds(backgrounds) -> np.ndarray:
    """The sensors' no-contact images: (320, 240, 3) uint8 RGB for every sensor, or (L, 320, 240, 3) (an
    array or a sequence of arrays) one per sensor, in sensor order -> that array, checked: InputError
    naming the background when it has the wrong shape or dtype or is grey. A background at another size of
    the DIGIT image's proportions is resized to it, as images are (``check_images``)."""
    if not isinstance(backgrounds, (list, tuple)):
        backgrounds = np.asarray(backgrounds)
        if backgrounds.ndim != 4:
            return _check_background(backgrounds, "background")
    if len(backgrounds) == 0:
        raise InputError("no background image given: pass one for all sensors or one per sensor")
    checked = [_check_background(np.asarray(b), f"background {i}") for i, b in enumerate(backgrounds)]
    if isinstance(backgrounds, np.ndarray) and backgrounds.shape[1:] == TACTILE_IMAGE_SHAPE:
        return backgrounds  # as given, no copy
    return np.stack(checked)


def _check_background(background: np.ndarray, name: str) -> np.ndarray:
    problem = tactile_size_problem(background.shape, name)
    if problem is not None:
        raise InputError(f"{problem} (no-contact images: one (320, 240, 3) for all sensors or (L, 320, 240, 3), "
                         "one per sensor)")
    if background.dtype != np.uint8:
        raise InputError(f"{name} has dtype {background.dtype}, no-contact images must be uint8 like the "
                         f"tactile images{_uint8_hint(background.dtype)}")
    background = sized_as_tactile(background, name)
    if is_grey(background):
        raise InputError(f"{name} is grey (its three channels are equal everywhere), but a DIGIT image is "
                         "RGB colour: read it in colour (tactile6d.data.hdf5.read_tactile_image, or cv2.imread without "
                         "IMREAD_GRAYSCALE, then cv2.cvtColor(image, cv2.COLOR_BGR2RGB))")
    return background


def backgrounds_per_sensor(backgrounds: np.ndarray, n_sensors: int) -> np.ndarray:
    """Checked backgrounds (``check_backgrounds``) -> (L, 320, 240, 3), one per sensor: a single one is
    repeated (a read-only view, no copy); InputError when their count is not the sensors'."""
    if backgrounds.ndim == 3:
        return np.broadcast_to(backgrounds, (n_sensors, *backgrounds.shape))
    if backgrounds.shape[0] != n_sensors:
        raise InputError(f"{backgrounds.shape[0]} background images for {n_sensors} sensors: give one for all "
                         "sensors or one per sensor, in sensor order")
    return backgrounds


# --- images that are plausibly read wrong ---------------------------------------------------------------

# An image passed in OpenCV's BGR order has its red and blue swapped. Against its own no-contact image the
# difference red - blue tells: as given it stays near the background's, swapped it is near minus that.
# Compared on a grid of every BGR_CHECK_STEP-th pixel, at the BGR_QUANTILE of the pixels, so that the
# pressed part of the gel (where the imprint changes red - blue) has little say. Measured against the
# default background: the paper's 120 images are within 5 grey levels that way and 5.4 or more times
# further swapped, and every one swapped is flagged (tests/test_inputs.py). Of 320 renderings (a box, a
# sphere, a cylinder, a cut box pressed 0.5-3 mm at random points and rolls) none is flagged, the closest
# matching 0.62 times as well swapped (flagged: below 1 / BGR_RATIO), and 284 are flagged swapped: a press
# that covers most of the gel leaves little to compare, and passes either way.
BGR_CHECK_STEP = 4
BGR_QUANTILE = 0.25
BGR_RATIO = 3.0  # swapped, the image must match at least this many times better ...
BGR_MIN_GAIN = 8.0  # ... and by this many grey levels, so that noise never decides


def is_grey(image: np.ndarray) -> bool:
    """Whether a (H, W, 3) image's three channels are equal everywhere (a grey image stacked to RGB)."""
    # A colour image shows it on a coarse grid already: the whole image is compared only when that is grey.
    for part in (image[::BGR_CHECK_STEP, ::BGR_CHECK_STEP], image):
        if not (np.array_equal(part[..., 0], part[..., 1]) and np.array_equal(part[..., 1], part[..., 2])):
            return False
    return True


def background_mismatch(image: np.ndarray, background: np.ndarray) -> tuple[float, float]:
    """How far a (320, 240, 3) uint8 RGB image's red - blue is from its no-contact image's (320, 240, 3), as
    given and with red and blue swapped: the ``BGR_QUANTILE`` over a pixel grid of the absolute
    difference (grey levels)."""
    grid = image[::BGR_CHECK_STEP, ::BGR_CHECK_STEP].astype(np.int16)
    reference = background[::BGR_CHECK_STEP, ::BGR_CHECK_STEP].astype(np.int16)
    red_minus_blue = grid[..., 0] - grid[..., 2]
    expected = reference[..., 0] - reference[..., 2]
    as_given = float(np.quantile(np.abs(red_minus_blue - expected), BGR_QUANTILE))
    swapped = float(np.quantile(np.abs(-red_minus_blue - expected), BGR_QUANTILE))
    return as_given, swapped


def looks_like_bgr(image: np.ndarray, background: np.ndarray) -> bool:
    """Whether an RGB image matches its no-contact image far better with R and B swapped (``BGR_RATIO``,
    ``BGR_MIN_GAIN``): the image was most likely passed in OpenCV's BGR order."""
    as_given, swapped = background_mismatch(image, background)
    return as_given > BGR_RATIO * swapped and as_given - swapped > BGR_MIN_GAIN


def image_problem(i: int, image: np.ndarray, background: np.ndarray) -> str | None:
    """Why image i (320, 240, 3) uint8 is plausibly wrong against its own no-contact image (320, 240, 3): grey,
    or its channels swapped (BGR passed as RGB); None when neither."""
    if is_grey(image):
        return (f"image {i} is grey (its three channels are equal everywhere), but a DIGIT image is RGB colour: "
                "read it in colour (tactile6d.data.hdf5.read_tactile_image, or cv2.imread without IMREAD_GRAYSCALE, "
                "then cv2.cvtColor(image, cv2.COLOR_BGR2RGB))")
    if looks_like_bgr(image, background):
        as_given, swapped = background_mismatch(image, background)
        return (f"image {i} looks like BGR: its red - blue differs from its no-contact image's by {as_given:.0f} "
                f"grey levels as given and by {swapped:.0f} swapped; pass RGB images: use read_tactile_image or "
                "convert with cv2.cvtColor(image, cv2.COLOR_BGR2RGB)")
    return None


def check_images_against_backgrounds(images: np.ndarray, backgrounds: np.ndarray) -> None:
    """InputError naming the first image (L, 320, 240, 3) uint8 that is grey or looks BGR against its own
    no-contact image (backgrounds (L, 320, 240, 3), ``backgrounds_per_sensor``): ``image_problem``'s."""
    for i, (image, background) in enumerate(zip(images, backgrounds)):
        problem = image_problem(i, image, background)
        if problem is not None:
            raise InputError(problem)


# --- sensor layouts that cannot be right, or say little ----------------------------------------------

# Sensors whose bodies overlap by more than this (m) on every axis are an error; less is taken for a
# calibration error of sensors mounted side by side. Poses declared off (``sensors.pose_sigma_*``) widen it:
# ``body_overlap_margin``.
BODY_OVERLAP_MARGIN = 0.5e-3


def body_overlap_margin(pose_tolerance: float) -> float:
    """How far (m) each DIGIT body is shrunk before the overlap test, for sensor poses whose relative error
    may reach ``pose_tolerance`` (m; ``SensorSettings.pair_distance_tolerance``, two standard deviations of
    two sensors' relative error at the gel): half of it, since both bodies shrink, and never less than
    ``BODY_OVERLAP_MARGIN``. Two fingertips side by side, reported through a hand's kinematics, overlap
    by a millimetre or two in about one scene in a hundred at 1.5 mm and 1.5 deg
    (docs/real_sensors.md); a wrong pose file (a sensor given twice, a frame mixed up) by centimetres."""
    return max(BODY_OVERLAP_MARGIN, 0.5 * float(pose_tolerance))


class UnderdeterminedPoseWarning(UserWarning):
    """One sensor only: the pose is under-determined (see ``warn_if_underdetermined``)."""


def check_bodies_apart(T_world_sensors: np.ndarray, margin: float = BODY_OVERLAP_MARGIN) -> None:
    """InputError naming the first two sensors (L, 4, 4) whose DIGIT bodies (``sensor.bodies_overlap``, each
    shrunk by ``margin``, see ``body_overlap_margin``) overlap: two units cannot be in one place."""
    T = np.asarray(T_world_sensors, dtype=np.float64)
    centres = T[:, :3, 3] + T[:, :3, :3] @ BOX_CENTER
    # Boxes whose bounding spheres are apart need no 15-axis test.
    reach = 2.0 * float(np.linalg.norm(BOX_HALF_EXTENTS))
    for j in range(len(T)):
        for i in range(j):
            if np.linalg.norm(centres[j] - centres[i]) < reach and bodies_overlap(T[i], T[j], margin):
                raise InputError(f"sensors {i} and {j} overlap: their DIGIT bodies intersect, so their poses "
                                 "cannot both be right (check the sensor order and the hand's calibration)")


def warn_if_underdetermined(n_sensors: int, stacklevel: int = 4) -> None:
    """A warning (``UnderdeterminedPoseWarning``) for one sensor: a single contact does not observe the
    rotation about its normal nor a slide along the surface, so the estimate is one of many that fit.
    stacklevel: as ``warnings.warn``'s; 4 names the line that called ``Estimator.estimate``."""
    if n_sensors == 1:
        warnings.warn("one sensor only: the pose is under-determined (the rotation about the contact normal "
                      "and sliding along the surface are not observed)", UnderdeterminedPoseWarning,
                      stacklevel=stacklevel)


# --- sensors that cannot all touch the object, and estimates that press into a sensor --------------------

# How far from a sensor's landmark (``sensor.contact_points``) the object can touch its gel: the gel's apex
# ahead of it and the gel's corners (m).
GEL_REACH = float(np.linalg.norm([GEL_CENTER[0] - CONTACT_POINT[0], GEL_WIDTH / 2, GEL_HEIGHT / 2]))
# Slack (m) beyond the object's extent, the gels' reach and the sensor poses' tolerance before sensors are
# called too far apart: the check is for poses that are wrong by far (units, frames), never a close call.
REACH_MARGIN = 0.01


# Touching sensors this far apart (m) are a mistake in the poses, whatever the object: no hand's fingertips are a
# metre apart. Closer but out of an object's reach, they say that the object is not this one, which the selection
# finds (``NoMatch``: identification moves on to the next object).
HAND_SPAN = 1.0


def check_sensors_within_reach(T_world_sensors: np.ndarray, touching: np.ndarray, object_extent: float,
                               pose_tolerance: float) -> None:
    """InputError naming the first two touching sensors that are ``HAND_SPAN`` or more apart and too far apart for
    one object to touch both: farther than ``object_extent`` (m, at least the object's diameter, e.g. its bounding
    box's diagonal) plus each gel's reach (``GEL_REACH``), ``pose_tolerance`` (m, ``pair_distance_tolerance``) and
    ``REACH_MARGIN``. When they would be within reach read as millimetres, it says so. T_world_sensors (L, 4, 4);
    touching (L,) bool (``Contacts.touching``: a lifted finger may be anywhere)."""
    points = contact_points(np.asarray(T_world_sensors, dtype=np.float64))
    on = np.flatnonzero(np.asarray(touching, dtype=bool))
    allowed = float(object_extent) + 2.0 * GEL_REACH + float(pose_tolerance) + REACH_MARGIN
    for b in on:
        for a in on[on < b]:
            distance = float(np.linalg.norm(points[b] - points[a]))
            if distance <= max(allowed, HAND_SPAN):
                continue
            hint = ("sensor poses are in metres, and these look like millimetres: divide the translations by 1000"
                    if distance / 1000.0 <= allowed else "check the sensor poses and their order")
            raise InputError(f"sensors {a} and {b} both touch, but their contacts are {distance:.3g} m apart and the "
                             f"object spans at most {object_extent:.3g} m: no pose can touch both; {hint}")


class PenetrationWarning(UserWarning):
    """The best pose presses deep into a sensor: the sensor poses are likely wrong, or an image's contact misread
    against another unit's no-contact image (``warn_if_pressed_in``)."""


# How far (m) beyond the sensor poses' declared error (the ranking's penetration allowance) the best pose may
# press into a sensor before the estimate is warned about. On the pipeline's scene sets the best pose
# presses at most 3 mm beyond it (docs/real_sensors.md); a sensor pose given inverted, about 8 mm.
PENETRATION_WARNING = 0.005


def warn_if_pressed_in(penetrations: np.ndarray, allowance: float, stacklevel: int = 4,
                       misread: Sequence[int] = ()) -> None:
    """A ``PenetrationWarning`` when the best pose's deepest penetration, penetrations (L,) m per sensor (NaN
    for none), exceeds ``allowance`` (m, ``SensorSettings.contact_sigma``) by more than ``PENETRATION_WARNING``:
    no pose explains the contacts without pressing into a sensor. misread: the sensors whose images were read
    against a no-contact image of another unit (``photometric.UnitWarning``), whose contacts are then the likelier
    cause, which the warning names instead of the sensor poses. stacklevel: as ``warnings.warn``'s."""
    depths = np.nan_to_num(np.asarray(penetrations, dtype=np.float64), nan=0.0)
    if depths.size == 0 or depths.max() <= allowance + PENETRATION_WARNING:
        return
    i = int(np.argmax(depths))
    if misread:
        several = len(misread) > 1
        cause = (f"Image{'s' if several else ''} {', '.join(str(j) for j in misread)} "
                 f"{'were' if several else 'was'} read against another unit's no-contact image (the warning above): "
                 f"the contacts read from {'them' if several else 'it'} are the likelier fault, not the sensor "
                 "poses; pass each unit's own no-contact image")
    else:
        cause = ("Check that each pose is T_world_sensor (the sensor's frame in the world, not its inverse), in "
                 "metres, in the DIGIT frame of docs/design.md, and in the images' order")
    warnings.warn(f"the best pose presses {1e3 * depths[i]:.1f} mm into sensor {i}'s body, "
                  f"{1e3 * (depths[i] - allowance):.1f} mm more than the sensor poses' declared error allows "
                  "(sensors.pose_sigma_mm, sensors.pose_sigma_deg): no pose fits the contacts without pressing into a "
                  f"sensor, so the estimate is likely wrong. {cause}", PenetrationWarning, stacklevel=stacklevel)
