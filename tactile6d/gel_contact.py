"""Where an object at a given pose presses into each sensor's gel, and whether two poses press alike.

The geometry is the simulator's (``tactile6d.render``): one ray per ``step`` x ``step`` pixel block from
the DIGIT camera, the object's camera-facing triangles in front of the gel, the first hit of each ray
(Embree), and the press depth ``gel distance - hit distance`` along the camera axis (sensor +x). Nothing
is shaded, so a sensor costs one small ray cast; the depth equals the ``depth`` of
``DigitRenderer(render_step=step, strict=False).contact`` exactly (no force shift, as the scenes use).

The image-consistent contact metric compares the contact masks (``depth > 0``) predicted at an estimated
pose and at the true pose, sensor by sensor, by their intersection over union.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import trimesh

from tactile6d import sensor
from tactile6d.errors import InputError
from tactile6d.geometry import invert_pose
from tactile6d.render import (
    CAMERA_POSITION,
    CAMERA_YFOV,
    MeshArrays,
    _front_triangles,
    _RayCaster,
    _transform_rows,
    gel_surface,
    mesh_arrays,
    pixel_rays,
)


@dataclass(frozen=True)
class GelGrid:
    """The renderer's ray grid for one ``step``, flattened row-major.

    shape (h, w); rays (h, w, 3) float32 with x component 1 (DIGIT frame); gel_t (h * w,) float32 m:
    the camera-axis distance at which each ray meets the gel; half_y, half_z m: the half extents of the
    view box between the camera and the gel apex plane; focal: pixels of the grid.
    """

    step: int
    shape: tuple[int, int]
    rays: np.ndarray
    gel_t: np.ndarray
    half_y: float
    half_z: float
    focal: float


@functools.lru_cache(maxsize=8)
def gel_grid(step: int, width: int = sensor.IMAGE_WIDTH, height: int = sensor.IMAGE_HEIGHT) -> GelGrid:
    """The ray grid of a ``width`` x ``height`` DIGIT image cast every ``step`` pixels (as ``DigitRenderer``
    builds it for ``render_step=step``). Cached: the grid is read-only."""
    if step < 1 or width % step or height % step:
        raise InputError(f"ray-grid step {step} must divide the image size {width}x{height}")
    rays = pixel_rays(width, height, step)
    gel_points, _ = gel_surface(rays)
    apex = sensor.GEL_CENTER[0]
    grid = GelGrid(
        step=int(step),
        shape=rays.shape[:2],
        rays=np.ascontiguousarray(rays, dtype=np.float32),
        gel_t=(gel_points[..., 0] - CAMERA_POSITION[0]).ravel().astype(np.float32),
        half_y=float(np.abs(rays[..., 1]).max() * apex) + 1e-4,
        half_z=float(np.abs(rays[..., 2]).max() * apex) + 1e-4,
        focal=(height / 2.0) / np.tan(CAMERA_YFOV / 2.0) / step,
    )
    grid.rays.flags.writeable = False
    grid.gel_t.flags.writeable = False
    return grid


def _triangles_to_window(triangles: np.ndarray, grid: GelGrid) -> tuple[int, int, int, int]:
    """Row and column range (r0, r1, c0, c1) of the grid that triangles (k, 3, 3), DIGIT frame, can cover.

    Conservative: a ray outside the window cannot hit them, so the window only saves casting.
    """
    h, w = grid.shape
    pts = triangles.reshape(-1, 3) - CAMERA_POSITION
    if np.any(pts[:, 0] <= 1e-4):  # a corner beside or behind the camera: projections blow up
        return 0, h, 0, w
    cols = w / 2.0 - pts[:, 1] / pts[:, 0] * grid.focal - 0.5
    rows = h / 2.0 - pts[:, 2] / pts[:, 0] * grid.focal - 0.5
    r0 = int(np.clip(np.floor(rows.min()), 0, h))
    r1 = int(np.clip(np.ceil(rows.max()) + 1, 0, h))
    c0 = int(np.clip(np.floor(cols.min()), 0, w))
    c1 = int(np.clip(np.ceil(cols.max()) + 1, 0, w))
    return r0, r1, c0, c1


def pose_to_front(arrays: MeshArrays, T_sensor_object: np.ndarray, grid: GelGrid) -> tuple[np.ndarray, np.ndarray]:
    """The object's triangles that can press the gel and the grid cells where they can.

    arrays: ``render.mesh_arrays`` of the mesh; T_sensor_object (4, 4) -> triangles (k, 3, 3) in the
    DIGIT frame, pixels (n,) int: flat indices into the grid (row-major), empty when nothing can press.
    """
    T = np.asarray(T_sensor_object, dtype=np.float64)
    nothing = np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64)
    vertices = _transform_rows(T[:3, :3], T[:3, 3], arrays.vertex_rows).T  # (V, 3) view
    faces = _front_triangles(vertices, arrays.faces, sensor.GEL_CENTER[0], grid.half_y, grid.half_z)
    if len(faces) == 0:
        return nothing
    triangles = vertices[arrays.faces[faces]]
    r0, r1, c0, c1 = _triangles_to_window(triangles, grid)
    if r0 >= r1 or c0 >= c1:
        return nothing
    pixels = (np.arange(r0, r1)[:, None] * grid.shape[1] + np.arange(c0, c1)[None, :]).ravel()
    # A hit counts only in front of the gel, and no hit lies nearer the camera than the nearest corner
    # (the rays' x component is 1): the rays whose gel lies nearer cannot press. The margin covers
    # Embree's float32 rounding, so the rays kept include every one the renderer finds pressed.
    nearest = triangles[..., 0].min() - CAMERA_POSITION[0]
    pixels = pixels[grid.gel_t[pixels] > nearest - 1e-6]
    return triangles, pixels


def pose_to_gel_depth(arrays: MeshArrays, T_sensor_object: np.ndarray, grid: GelGrid, caster: _RayCaster) -> np.ndarray:
    """How far the object at ``T_sensor_object`` (4, 4) presses into the gel: (h, w) float32 m, 0 where not.

    arrays: ``render.mesh_arrays`` of the mesh; grid: ``gel_grid``; caster: a ``render._RayCaster``
    (one per thread). The same triangles, rays and hit test as ``DigitRenderer.contact``.
    """
    depth = np.zeros(grid.shape[0] * grid.shape[1], dtype=np.float32)
    triangles, pixels = pose_to_front(arrays, T_sensor_object, grid)
    if len(pixels):
        t, prim, _, _ = caster.first_hits(triangles, grid.rays.reshape(-1, 3)[pixels])
        hit = (prim >= 0) & (t < grid.gel_t[pixels])
        depth[pixels[hit]] = grid.gel_t[pixels[hit]] - t[hit]
    return depth.reshape(grid.shape)


def poses_to_gel_depths(
    mesh: trimesh.Trimesh | MeshArrays,
    T_world_object: np.ndarray,
    T_world_sensors: np.ndarray,
    step: int,
    caster: _RayCaster | None = None,
) -> np.ndarray:
    """Each sensor's press depth for each object pose.

    mesh: the object (its own frame); T_world_object (P, 4, 4) or (4, 4); T_world_sensors (L, 4, 4);
    step: ray-grid step in pixels (divides 240 and 320). -> depth (P, L, h, w) float32 m, 0 where the
    object does not press into the gel; (h, w) = (320, 240) / step, row 0 at the top of the image.
    caster: reuse one across calls to save creating an Embree device. The depths are bit-identical to
    ``DigitRenderer.contact``'s on the same grid.
    """
    arrays = mesh_arrays(mesh)
    T_objects = np.asarray(T_world_object, dtype=np.float64).reshape(-1, 4, 4)
    T_sensors = np.asarray(T_world_sensors, dtype=np.float64).reshape(-1, 4, 4)
    grid = gel_grid(int(step))
    caster = _RayCaster() if caster is None else caster
    out = np.zeros((len(T_objects), len(T_sensors), *grid.shape), dtype=np.float32)
    T_sensors_world = [invert_pose(T) for T in T_sensors]
    for p, T_wo in enumerate(T_objects):
        for i, T_sw in enumerate(T_sensors_world):
            # Composed one pair at a time, as DigitRenderer.render does, so the result is bit-identical.
            out[p, i] = pose_to_gel_depth(arrays, T_sw @ T_wo, grid, caster)
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
    caster: _RayCaster | None = None,
) -> dict[str, np.ndarray]:
    """The image-consistent contact metric of K estimates of one scene.

    T_world_object_est (K, 4, 4), T_world_object_gt (4, 4), T_world_sensors (L, 4, 4) -> dict with
    ``consistent`` (K,) bool (``masks_to_image_consistent``), ``iou`` (K, L) and ``empty_true`` (L,) bool
    (``empty_true_masks``).
    """
    T_est = np.asarray(T_world_object_est, dtype=np.float64).reshape(-1, 4, 4)
    T_gt = np.asarray(T_world_object_gt, dtype=np.float64).reshape(1, 4, 4)
    caster = _RayCaster() if caster is None else caster
    depths = poses_to_gel_depths(mesh, np.concatenate([T_gt, T_est]), T_world_sensors, step, caster)
    masks = depths > 0
    return {
        "consistent": masks_to_image_consistent(masks[1:], masks[0], iou_min),
        "iou": mask_iou(masks[1:], masks[0][None]),
        "empty_true": empty_true_masks(masks[0]),
    }
