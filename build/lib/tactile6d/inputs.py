"""Checks of what a caller hands the estimator: sensor poses and tactile images.

Each check returns the input as the array the steps take, or raises InputError naming the first
problem, so that a robot's mistake is reported before any work is done.
"""

from __future__ import annotations

import numpy as np

from tactile6d.errors import InputError
from tactile6d.geometry import is_rotation
from tactile6d.io import TACTILE_IMAGE_SHAPE


def check_sensor_poses(T_world_sensors) -> np.ndarray:
    """Sensor poses -> (L, 4, 4) float64, L >= 1; InputError naming the first bad one."""
    T = np.asarray(T_world_sensors, dtype=np.float64)
    if T.ndim == 2 and T.shape == (4, 4):
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] < 1:
        raise InputError(f"sensor poses must be (L, 4, 4) with L >= 1, got shape {T.shape}")
    for i, pose in enumerate(T):
        if not np.all(np.isfinite(pose)):
            raise InputError(f"sensor pose {i} has NaN or infinite entries")
        if not is_rotation(pose[:3, :3], atol=1e-5):
            raise InputError(f"sensor pose {i}: the upper-left 3x3 block is not a rotation matrix")
        if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0]):
            raise InputError(f"sensor pose {i}: the last row must be 0 0 0 1, got {pose[3].tolist()}")
    return T


def check_images(images, n_sensors: int) -> np.ndarray:
    """L tactile images (an array or a sequence of arrays) -> (L, 320, 240, 3) uint8, one per sensor."""
    if images is None:
        raise InputError("method 'ours' needs one tactile image per sensor, got none")
    if isinstance(images, np.ndarray) and images.ndim == 4:
        images = list(images)
    elif isinstance(images, np.ndarray):
        raise InputError(f"tactile images must be (L, 320, 240, 3), got shape {images.shape}")
    if len(images) != n_sensors:
        raise InputError(f"{len(images)} tactile images for {n_sensors} sensor poses")
    for i, image in enumerate(images):
        image = np.asarray(image)
        if image.shape != TACTILE_IMAGE_SHAPE:
            raise InputError(f"image {i} has shape {image.shape}, a DIGIT image is (320, 240, 3): "
                             "320 rows x 240 columns x RGB")
        if image.dtype != np.uint8:
            raise InputError(f"image {i} has dtype {image.dtype}, tactile images must be uint8")
    return np.stack([np.asarray(image) for image in images])
