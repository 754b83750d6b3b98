"""The DIGIT sensor's geometry, in the frame of ``digit.STL``, and how to place one on a surface.

The camera looks along +x. The gel is a 20 mm (y) x 30 mm (z) patch centred at ``GEL_CENTER`` that bulges
toward the object. A sensor touches a surface point ``p`` with outward normal ``n`` when its +x axis is
``-n``; the paper's "contact point" (landmark) ``CONTACT_POINT`` then lies on ``p`` or just outside it.
Frames and placement: docs/design.md, Conventions.
"""

from __future__ import annotations

import numpy as np

from tactile6d.core.geometry import make_pose, orthonormal_frame, rotvec_to_rotmat

IMAGE_WIDTH = 240  # pixels, along the sensor's y axis
IMAGE_HEIGHT = 320  # pixels, along the sensor's z axis

CONTACT_POINT = np.array([0.020, 0.0, 0.015])  # the paper's landmark: t + R @ CONTACT_POINT
GEL_CENTER = np.array([0.022, 0.0, 0.015])  # apex of the gel, the point pressed deepest
GEL_WIDTH = 0.020  # along y
GEL_HEIGHT = 0.030  # along z

# The collision proxy the paper gave PhysX for a DIGIT body.
BOX_CENTER = np.array([0.0035, 0.0, 0.017])
BOX_HALF_EXTENTS = np.array([0.0161, 0.0135, 0.017])

# With the gel apex pressed ``depth`` into the surface, the contact point sits
# ``GEL_CENTER[0] - CONTACT_POINT[0] - depth`` outside it.
_APEX_AHEAD_OF_CONTACT = GEL_CENTER[0] - CONTACT_POINT[0]


def sensor_poses_touching(
    points: np.ndarray, normals: np.ndarray, rolls: np.ndarray | float = 0.0, depths: np.ndarray | float = 0.0018
) -> np.ndarray:
    """Sensor poses that press the gel into a surface, in the surface's frame.

    points (..., 3), normals (..., 3) outward, rolls (...) radians, depths (...) metres -> T (..., 4, 4),
    ``T_surfaceframe_sensor``.

    Rule (docs/design.md, Conventions): the sensor's +x axis is ``-normal``. At roll 0 its y and z axes
    come from ``geometry.orthonormal_frame(-normal)``; ``roll`` turns the sensor about its +x axis.
    The gel apex ``GEL_CENTER`` is placed ``depth`` inside the surface along ``-normal`` (the default
    1.8 mm is about the median imprint depth of the paper's triplets), so the contact point
    ``CONTACT_POINT`` lies ``2 mm - depth`` outside the surface.
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    normals = normals / np.linalg.norm(normals, axis=-1, keepdims=True)
    rolls = np.broadcast_to(np.asarray(rolls, dtype=np.float64), points.shape[:-1])
    depths = np.broadcast_to(np.asarray(depths, dtype=np.float64), points.shape[:-1])
    R0 = orthonormal_frame(-normals)
    R = R0 @ rotvec_to_rotmat(rolls[..., None] * np.array([1.0, 0.0, 0.0]))
    contact = points + (_APEX_AHEAD_OF_CONTACT - depths)[..., None] * normals
    t = contact - (R @ CONTACT_POINT[:, None])[..., 0]
    return make_pose(R, t)


def sensor_poses_to_surface_points(T_frame_sensors: np.ndarray, depths: np.ndarray | float) -> np.ndarray:
    """The surface points that sensors placed by ``sensor_poses_touching`` touch: its inverse for the points.

    T_frame_sensors (..., 4, 4) sensor poses in the surface's frame, depths (...) metres pressed into the
    surface -> points (..., 3) in that frame, metres. The contact point ``CONTACT_POINT`` lies
    ``GEL_CENTER.x - CONTACT_POINT.x - depth`` outside the surface along the outward normal (the sensor's
    -x axis, ``contact_normals``).
    """
    gap = _APEX_AHEAD_OF_CONTACT - np.asarray(depths, dtype=np.float64)
    return contact_points(T_frame_sensors) - gap[..., None] * contact_normals(T_frame_sensors)


def contact_points(T_frame_sensor: np.ndarray) -> np.ndarray:
    """(..., 4, 4) sensor poses -> (..., 3): the paper's landmark ``t + R @ CONTACT_POINT``."""
    T = np.asarray(T_frame_sensor, dtype=np.float64)
    return T[..., :3, 3] + (T[..., :3, :3] @ CONTACT_POINT[:, None])[..., 0]


def contact_normals(T_frame_sensor: np.ndarray) -> np.ndarray:
    """(..., 4, 4) -> (..., 3): the outward surface normal a touching sensor implies (its -x axis)."""
    return -np.asarray(T_frame_sensor, dtype=np.float64)[..., :3, 0]


def bodies_overlap(T_a: np.ndarray, T_b: np.ndarray, margin: float = 0.0) -> bool:
    """Whether the DIGIT bodies (the box ``BOX_CENTER``, ``BOX_HALF_EXTENTS``) of sensors at T_a and T_b
    (4, 4), each shrunk by ``margin`` (m) on every side, intersect.

    Separating-axis test: two convex boxes are apart exactly when their projections on one of 15 axes
    are: the 3 face normals of each box and the 9 cross products of an edge of one with an edge of the
    other (parallel edges give no axis; the face normals cover that case).
    """
    R_a, R_b = np.asarray(T_a, dtype=np.float64)[:3, :3], np.asarray(T_b, dtype=np.float64)[:3, :3]
    offset = (np.asarray(T_b, dtype=np.float64)[:3, 3] + R_b @ BOX_CENTER) - (
        np.asarray(T_a, dtype=np.float64)[:3, 3] + R_a @ BOX_CENTER)
    half = BOX_HALF_EXTENTS - margin
    edges = np.cross(R_a.T[:, None, :], R_b.T[None, :, :]).reshape(9, 3)
    lengths = np.linalg.norm(edges, axis=1)
    keep = lengths > 1e-9
    axes = np.concatenate([R_a.T, R_b.T, edges[keep] / lengths[keep, None]])
    reach = np.abs(axes @ R_a) @ half + np.abs(axes @ R_b) @ half
    return bool(np.all(np.abs(axes @ offset) <= reach))
