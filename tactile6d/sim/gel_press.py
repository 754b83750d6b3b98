"""Where an object at a given pose presses into each sensor's gel, and whether two poses press alike.

The geometry is the simulator's (``tactile6d.sim.render``): one ray per ``step`` x ``step`` pixel block from
the DIGIT camera, the object's camera-facing triangles in front of the gel, the first hit of each ray
(Embree), and the press depth ``gel distance - hit distance`` along the camera axis (sensor +x): the
renderer's own (``contact_depth``, the depth of ``contact`` without its shading), with
``render_step=step``, ``strict=False`` and no force shift, as the scenes use.

Many (pose, sensor) pairs are cast at once: the object's triangles are put in one Embree scene in the
object's frame, built once per mesh, and every pair's rays are brought into that frame (the renderer
instead poses the mesh and builds a scene per pair, which costs ten times the rays' traversal). The hit
triangle's distance is then recomputed as the renderer recomputes it, from the corners posed in the
sensor frame, so that a pair's depths are the renderer's bit for bit wherever both pick the same
triangle. They may pick different ones where a ray passes within about 0.1 micrometre of a triangle's
edge, since Embree works in single precision and the object frame's coordinates are other numbers: between
two triangles that share the edge the depths then differ by the bend there, far below a micrometre, but
at the object's outline one cast may hit where the other misses, and the depth there differs by the whole
press at that ray (up to 2 mm on the tracked sequences, on a few rays in a thousand; docs/speed.md). The
renderer leaves out the triangles that face away from the camera; the whole mesh's first hit on such a
triangle (a ray entering through a hole, or a camera inside the object) sends that pair to the renderer
itself.

The image-consistent contact metric compares the contact masks (``depth > 0``) predicted at an estimated
pose and at the true pose, sensor by sensor, by their intersection over union.
"""

from __future__ import annotations

import functools
import weakref

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from tactile6d.core import sensor
from tactile6d.core.geometry import invert_pose
from tactile6d.sim.render import CAMERA_POSITION, DigitRenderer, MeshArrays, mesh_arrays, ray_triangle_hits

# Rays per Embree call: bounds the batch's buffers (about 40 bytes a ray) whatever the number of pairs.
_RAYS_PER_CAST = 1 << 18


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


class _ObjectScene:
    """A mesh's triangles in one Embree scene, in the object's own frame (float32), and the mesh's arrays."""

    def __init__(self, arrays: MeshArrays):
        self.arrays = arrays
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self.scene, arrays.vertex_rows.T[arrays.faces].astype(np.float32))

    def first_hits(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        """(m, 3) float32 origins and directions, (m,) float32 far limits -> (m,) face index or -1."""
        return self.scene.run(origins, directions, dists=t_max, output=1)["primID"]


_SCENES: dict[int, tuple[weakref.ref, _ObjectScene]] = {}


def _object_scene(mesh: trimesh.Trimesh | MeshArrays) -> _ObjectScene:
    """The scene of ``mesh``, built on its first use and kept while the mesh object lives."""
    key = id(mesh)
    entry = _SCENES.get(key)
    if entry is not None and entry[0]() is mesh:
        return entry[1]
    scene = _ObjectScene(mesh_arrays(mesh))
    # The callback holds the dict itself: at interpreter exit the module's globals may be gone before the
    # last meshes are, and a lookup of the global name would then fail inside the callback.
    _SCENES[key] = (weakref.ref(mesh, lambda _, key=key, scenes=_SCENES: scenes.pop(key, None)), scene)
    return scene


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
    The renderer's ``contact_depth`` of each pair (module docstring: how, and where they may differ).
    """
    scene = _object_scene(mesh)
    T_objects = np.asarray(T_world_object, dtype=np.float64).reshape(-1, 4, 4)
    T_sensors = np.asarray(T_world_sensors, dtype=np.float64).reshape(-1, 4, 4)
    renderer = depth_renderer(int(step))
    rays, gel_t = renderer.ray_grid()
    T_sensors_world = [invert_pose(T) for T in T_sensors]
    # Composed one pair at a time, as DigitRenderer.render does, so that the posed corners are its bits.
    pairs = np.stack([T_sw @ T_wo for T_wo in T_objects for T_sw in T_sensors_world])
    depth = np.zeros((len(pairs), len(rays)), dtype=np.float32)
    per_cast = max(1, _RAYS_PER_CAST // len(rays))
    for start in range(0, len(pairs), per_cast):
        chunk = np.arange(start, min(start + per_cast, len(pairs)))
        for k, pressed in zip(chunk, _cast_pairs(scene, pairs[chunk], rays, gel_t)):
            depth[k] = renderer.contact_depth(scene.arrays, pairs[k]).ravel() if pressed is None else pressed
    return depth.reshape(len(T_objects), len(T_sensors), *renderer.grid_shape)


def _cast_pairs(scene: _ObjectScene, T_sensor_objects: np.ndarray, rays: np.ndarray, gel_t: np.ndarray) -> list:
    """The press depths (n,) float32 of K pairs T_sensor_object (K, 4, 4) on the ray grid (rays (n, 3),
    gel_t (n,)), or None for a pair with a first hit on a triangle that faces away from the camera (left
    to the renderer)."""
    K, n = len(T_sensor_objects), len(rays)
    T_object_sensors = np.stack([invert_pose(T) for T in T_sensor_objects])
    R = T_object_sensors[:, :3, :3]
    origins = R @ CAMERA_POSITION + T_object_sensors[:, :3, 3]  # (K, 3): the camera in the object frame
    directions = (rays.astype(np.float64) @ R.transpose(0, 2, 1)).astype(np.float32).reshape(-1, 3)
    t_max = np.nextafter(gel_t, np.float32(np.inf))  # just past the gel, as the renderer stops its rays
    face = scene.first_hits(np.repeat(origins.astype(np.float32), n, axis=0), directions, np.tile(t_max, K))
    hit = np.flatnonzero(face >= 0)
    pair, ray = hit // n, hit % n
    # The hit triangles' corners posed in the sensor frame with the renderer's arithmetic
    # (``_transform_rows``: each coordinate ((x R0 + R1 y) + R2 z) + t), one pair's pose per corner.
    corner_ids = scene.arrays.faces[face[hit]].ravel()  # (3m,)
    owner = np.repeat(pair, 3)
    x, y, z = scene.arrays.vertex_rows[:, corner_ids]
    coefficients = np.ascontiguousarray(T_sensor_objects[:, :3, :].transpose(1, 2, 0))  # (3, 4, K)
    posed = np.empty((3, len(corner_ids)))
    for i in range(3):
        c = coefficients[i]
        np.multiply(x, c[0][owner], out=posed[i])
        posed[i] += c[1][owner] * y
        posed[i] += c[2][owner] * z
        posed[i] += c[3][owner]
    posed = posed.T.reshape(-1, 3, 3)
    normal = np.cross(posed[:, 1] - posed[:, 0], posed[:, 2] - posed[:, 0])
    facing = np.sum(normal * (posed[:, 0] - CAMERA_POSITION), axis=1) < 0.0
    corners = (posed - CAMERA_POSITION).astype(np.float32).astype(np.float64)
    t = ray_triangle_hits(corners, rays[ray].astype(np.float64))[0]
    front = t < gel_t[ray]
    depth = np.zeros((K, n), dtype=np.float32)
    depth[pair[front], ray[front]] = gel_t[ray[front]] - t[front]
    away = set(pair[~facing].tolist())
    return [None if k in away else depth[k] for k in range(K)]


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
