"""Where an object at a given pose presses into each sensor's gel, and whether two poses press alike.

The geometry is the simulator's (``tactile6d.sim.render``): one ray per ``step`` x ``step`` pixel block from
the DIGIT camera, the object's camera-facing triangles in front of the gel, the first hit of each ray
(Embree), and the press depth ``gel distance - hit distance`` along the camera axis (sensor +x): the
renderer's own (``contact_depth``, the depth of ``contact`` without its shading), with
``render_step=step``, ``strict=False`` and no force shift, as the scenes use.

The image-consistent contact metric compares the contact masks (``depth > 0``) predicted at an estimated
pose and at the true pose, sensor by sensor, by their intersection over union.
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from tactile6d.core import sensor
from tactile6d.core.geometry import invert_pose
from tactile6d.sim.render import DigitRenderer, MeshArrays, mesh_arrays


@functools.lru_cache(maxsize=8)
def depth_renderer(step: int) -> DigitRenderer:
    """The simulator on the ray grid of ``step`` pixels, used for its geometry only.

    Its depth depends on nothing but the grid, the object and the pose: the background, lights and
    noise only shade, so a blank background serves. ``strict=False`` measures any press, however deep
    (an estimate may push an object into a sensor); ``force=0`` as in the scene sets. Cached: one
    Embree device per step and process (a renderer is not thread-safe).
    """
    blank = np.zeros((sensor.IMAGE_HEIGHT, sensor.IMAGE_WIDTH, 3), dtype=np.uint8)
    return DigitRenderer.from_default_config(blank, render_step=int(step), strict=False, force=0.0, workers=1)


def poses_to_gel_depths(
    mesh: trimesh.Trimesh | MeshArrays,
    T_world_object: np.ndarray,
    T_world_sensors: np.ndarray,
    step: int,
) -> np.ndarray:
    """Each sensor's press depth for each object pose.

    mesh: the object (its own frame); T_world_object (P, 4, 4) or (4, 4); T_world_sensors (L, 4, 4);
    step: ray-grid step in pixels (divides 240 and 320). -> depth (P, L, h, w) float32 m, 0 where the
    object does not press into the gel; (h, w) = (320, 240) / step, row 0 at the top of the image.
    """
    arrays = mesh_arrays(mesh)
    T_objects = np.asarray(T_world_object, dtype=np.float64).reshape(-1, 4, 4)
    T_sensors = np.asarray(T_world_sensors, dtype=np.float64).reshape(-1, 4, 4)
    renderer = depth_renderer(int(step))
    out = np.zeros((len(T_objects), len(T_sensors), *renderer.grid_shape), dtype=np.float32)
    T_sensors_world = [invert_pose(T) for T in T_sensors]
    for p, T_wo in enumerate(T_objects):
        for i, T_sw in enumerate(T_sensors_world):
            # Composed one pair at a time, as DigitRenderer.render does, so the result is bit-identical.
            out[p, i] = renderer.contact_depth(arrays, T_sw @ T_wo)
    return out


def mask_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of boolean masks a, b (..., h, w) -> (...) float64.

    Two empty masks agree perfectly: their IoU is 1 (not 0/0).
    """
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    inter = np.count_nonzero(a & b, axis=(-2, -1))
    union = np.count_nonzero(a | b, axis=(-2, -1))
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def masks_to_image_consistent(
    masks_est: np.ndarray, masks_true: np.ndarray, iou_min: float
) -> np.ndarray:
    """Whether estimates press every sensor where the true pose does.

    masks_est (..., L, h, w) bool: contact masks predicted at the estimated pose(s); masks_true (L, h, w)
    bool: predicted at the true pose. -> (...) bool: every sensor's IoU is at least ``iou_min``.

    A sensor whose true mask is empty (it does not touch the object at the true pose; the scene sets
    press every sensor 1.5-2 mm in, so this marks a broken scene, which ``empty_true_masks`` reports)
    counts as consistent exactly when the estimate predicts no contact there either, by ``mask_iou``'s
    rule for two empty masks.
    """
    return np.all(mask_iou(masks_est, np.asarray(masks_true, dtype=bool)) >= iou_min, axis=-1)


def empty_true_masks(masks_true: np.ndarray) -> np.ndarray:
    """masks_true (L, h, w) bool -> (L,) bool: sensors that do not touch the object at the true pose."""
    return ~np.any(np.asarray(masks_true, dtype=bool), axis=(-2, -1))


def image_consistency(
    mesh: trimesh.Trimesh | MeshArrays,
    T_world_object_est: np.ndarray,
    T_world_object_gt: np.ndarray,
    T_world_sensors: np.ndarray,
    step: int,
    iou_min: float,
) -> dict[str, np.ndarray]:
    """The image-consistent contact metric of K estimates of one scene.

    T_world_object_est (K, 4, 4), T_world_object_gt (4, 4), T_world_sensors (L, 4, 4) -> dict with
    ``consistent`` (K,) bool (``masks_to_image_consistent``), ``iou`` (K, L) and ``empty_true`` (L,) bool
    (``empty_true_masks``).
    """
    T_est = np.asarray(T_world_object_est, dtype=np.float64).reshape(-1, 4, 4)
    T_gt = np.asarray(T_world_object_gt, dtype=np.float64).reshape(1, 4, 4)
    depths = poses_to_gel_depths(mesh, np.concatenate([T_gt, T_est]), T_world_sensors, step)
    masks = depths > 0
    return {
        "consistent": masks_to_image_consistent(masks[1:], masks[0], iou_min),
        "iou": mask_iou(masks[1:], masks[0][None]),
        "empty_true": empty_true_masks(masks[0]),
    }
