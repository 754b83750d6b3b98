"""What a real set-up does to a clean generated scene: light that drifted since the no-contact images were
recorded, and sensor poses off by the error of a robot hand's forward kinematics.

Both act on a ``scenes.SceneSet`` after it was rendered, so a perturbed set has the same objects, poses
and contacts as its clean draw would (ground truth unchanged), only what the estimator is given changes:
- **light** (``drift_light``): each sensor of each scene gets its own gain per colour channel, uniform in
  ``1 +- gain_max``, and gamma per channel, uniform in ``gamma_range`` (``drift_image_light``), then
  Gaussian camera noise of ``noise_std`` grey levels. In a share ``rerecorded`` of the scenes the sensors'
  no-contact images were recorded again under the drifted light; in the others each sensor still has
  the no-contact image of before the drift. The set carries every sensor's no-contact image
  (``backgrounds``), as a user passes them.
- **kinematics** (``perturb_sensor_poses``): each sensor pose as recorded is the true one moved, in the
  sensor's own frame, by a translation with ``sigma_m`` per axis and a rotation vector with ``sigma_rad``
  per axis (Gaussian). The images are those of the true poses.
- **camera** (``through_camera``): every image and every sensor's no-contact image, which comes through the
  same camera, as a USB camera's stream delivers them: blurred (a lens slightly out of focus) and/or
  JPEG-compressed (a DIGIT streams MJPEG).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.sim.scenes import SceneSet


def drift_image_light(image: np.ndarray, gain, gamma) -> np.ndarray:
    """The forward model: image (H, W, 3) uint8 as it looks under light drifted by ``gain`` and ``gamma``
    (each a number or (3,) per channel), rounded to 8 bits: the model ``perception.photometric`` fits."""
    g = np.broadcast_to(np.asarray(gain, dtype=np.float64), (3,))
    e = np.broadcast_to(np.asarray(gamma, dtype=np.float64), (3,))
    x = np.asarray(image, dtype=np.float64) / 255.0
    return np.clip(np.rint(255.0 * g * x**e), 0, 255).astype(np.uint8)


def add_camera_noise(image: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    """image (..., 3) uint8 plus Gaussian noise of ``noise_std`` grey levels, rounded and clipped."""
    if noise_std <= 0:
        return np.asarray(image).copy()
    return np.clip(np.rint(image + rng.normal(0.0, noise_std, np.shape(image))), 0, 255).astype(np.uint8)


def jpeg_round_trip(image: np.ndarray, quality: int) -> np.ndarray:
    """image (H, W, 3) uint8 RGB encoded as a JPEG of ``quality`` (1-100) and decoded again (OpenCV's libjpeg,
    its default, accurate integer transform)."""
    ok, encoded = cv2.imencode(".jpg", np.ascontiguousarray(np.asarray(image)[..., ::-1]),
                               [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"JPEG encoding failed (quality {quality})")
    return np.ascontiguousarray(cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1])


def defocus(image: np.ndarray, sigma: float) -> np.ndarray:
    """image (H, W, 3) uint8 blurred by a Gaussian of ``sigma`` pixels (OpenCV's bit-exact 8-bit filter,
    kernel 2 ceil(3 sigma) + 1 wide), as a lens slightly out of focus gives it; sigma 0: a copy."""
    if sigma <= 0:
        return np.asarray(image).copy()
    k = 2 * int(np.ceil(3.0 * sigma)) + 1
    return cv2.GaussianBlur(np.asarray(image), (k, k), sigma, borderType=cv2.BORDER_REFLECT_101)


def through_camera(scenes: SceneSet, background: np.ndarray, jpeg_quality: int | None = None,
                   blur_sigma: float = 0.0) -> SceneSet:
    """``scenes`` as a camera's stream delivers them (module docstring): each image blurred by ``blur_sigma``
    pixels, then JPEG-compressed at ``jpeg_quality`` (None: not compressed) -> a new set whose ``backgrounds``
    (S, L, 320, 240, 3) are the no-contact image (320, 240, 3) uint8 RGB the scenes were rendered over (or each
    sensor's own, when the set carries them) through the same camera."""
    def camera(image: np.ndarray) -> np.ndarray:
        out = defocus(image, blur_sigma)
        return out if jpeg_quality is None else jpeg_round_trip(out, jpeg_quality)

    n, L = scenes.images.shape[:2]
    images = np.empty_like(scenes.images)
    backgrounds = np.empty_like(scenes.images)
    shared = camera(background) if scenes.backgrounds is None else None  # one no-contact image for all: once
    for s in range(n):
        own = scenes.backgrounds_of(s)
        for i in range(L):
            images[s, i] = camera(scenes.images[s, i])
            backgrounds[s, i] = shared if own is None else camera(own[i])
    return replace(scenes, images=images, backgrounds=backgrounds)


def drift_light(scenes: SceneSet, background: np.ndarray, gain_max: float, gamma_range: tuple[float, float],
                noise_std: float, rerecorded: float, rng: np.random.Generator) -> SceneSet:
    """``scenes`` with each sensor's light drifted (module docstring) -> a new set with ``backgrounds``
    (S, L, 320, 240, 3) uint8 RGB, each sensor's no-contact image as the user has it, and in ``extra``
    the drift drawn: ``light_gain`` and ``light_gamma`` (S, L, 3), ``background_rerecorded`` (S,) bool.
    background: (320, 240, 3) uint8 RGB, the no-contact image the scenes were rendered over."""
    n, L = scenes.images.shape[:2]
    gains = rng.uniform(1.0 - gain_max, 1.0 + gain_max, (n, L, 3))
    gammas = rng.uniform(gamma_range[0], gamma_range[1], (n, L, 3))
    again = rng.random(n) < rerecorded
    images = np.empty_like(scenes.images)
    backgrounds = np.empty_like(scenes.images)
    for s in range(n):
        for i in range(L):
            images[s, i] = add_camera_noise(drift_image_light(scenes.images[s, i], gains[s, i], gammas[s, i]),
                                            noise_std, rng)
            if again[s]:
                backgrounds[s, i] = add_camera_noise(drift_image_light(background, gains[s, i], gammas[s, i]),
                                                     noise_std, rng)
            else:
                backgrounds[s, i] = background
    extra = {**scenes.extra, "light_gain": gains, "light_gamma": gammas, "background_rerecorded": again}
    return replace(scenes, images=images, backgrounds=backgrounds, extra=extra)


def perturb_sensor_poses(scenes: SceneSet, sigma_m: float, sigma_rad: float, rng: np.random.Generator) -> SceneSet:
    """``scenes`` with each sensor pose as a robot's kinematics would report it (module docstring); the
    errors drawn go to ``extra``: ``pose_error_translation`` (S, L, 3) m and ``pose_error_rotvec`` (S, L, 3)
    rad, both in the sensor's frame."""
    shape = scenes.T_world_sensors.shape[:2] + (3,)
    translation = rng.normal(0.0, sigma_m, shape)
    rotvec = rng.normal(0.0, sigma_rad, shape)
    error = make_pose(rotvec_to_rotmat(rotvec), translation)
    extra = {**scenes.extra, "pose_error_translation": translation, "pose_error_rotvec": rotvec}
    return replace(scenes, T_world_sensors=scenes.T_world_sensors @ error, extra=extra)
