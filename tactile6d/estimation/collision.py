"""Penetration depth between an object, as convex pieces, and the DIGIT bodies (docs/design.md, The method).

A DIGIT body is the paper's PhysX proxy, a box of half extents ``sensor.BOX_HALF_EXTENTS`` centred at
``sensor.BOX_CENTER`` in the sensor frame. The object is a list of convex pieces (the paper's files,
a coacd decomposition, or one convex hull). The depth between the object and a sensor is the largest
of the pieces' penetration depths (the minimum translation that separates that piece from the box),
which is what a per-shape contact generator such as PhysX reports as the deepest contact; 0 when
apart.

Backend: python-fcl (``fcl.collide`` with contacts: GJK, then EPA for the depth), chosen over
pybullet's ``getClosestPoints`` by a measured comparison (docs/collision.md): fcl returns the exact
depth where pybullet adds its collision margin on mesh shapes, at the same speed, and fcl keeps no
global physics-client state. EPA can stop early on some vertex-edge contacts; ``poses_to_penetrations``
raises its depths to two cheap lower bounds. Poses are first screened with the pieces' bounding spheres against the box (exact point-box
distance), so pieces far from a sensor cost no fcl call and get depth exactly 0.

Units: metres. Poses are 4x4 float64, ``T_world_object`` and ``T_world_sensor``.
"""

from __future__ import annotations

from dataclasses import dataclass

import fcl
import numpy as np
import trimesh

from tactile6d.core.errors import MeshError
from tactile6d.core.geometry import invert_pose, make_pose
from tactile6d.core.sensor import BOX_CENTER, BOX_HALF_EXTENTS


@dataclass(frozen=True)
class ConvexPieces:
    """An object as convex pieces, in the object frame.

    vertices: K arrays (V_k, 3) m; faces: K arrays (F_k, 3) int, outward triangles of each hull;
    centers (K, 3) and radii (K,) m: a bounding sphere of each piece; inner_vertices: K arrays
    (<= INNER_VERTICES, 3), spread-out hull vertices whose own hull lies inside the piece, and
    inner_planes: K arrays (F'_k, 4) of that inner hull's outward planes (n, o), n . x <= o inside.
    The inner hulls give cheap lower bounds on penetration depth (``poses_to_vertex_depth_bounds``,
    ``poses_to_box_depth_bounds``).
    """

    vertices: tuple[np.ndarray, ...]
    faces: tuple[np.ndarray, ...]
    centers: np.ndarray
    radii: np.ndarray
    inner_vertices: tuple[np.ndarray, ...]
    inner_planes: tuple[np.ndarray, ...]


# Vertices kept in a piece's inner hull: enough for a tight bound on rounded shapes, few enough that
# the bounds stay cheap next to fcl's exact depths.
INNER_VERTICES = 48


def _spread_subset(points: np.ndarray, n: int) -> np.ndarray:
    """Indices of n points of (V, 3) spread out by farthest-point sampling, from the point farthest
    from the centroid (deterministic)."""
    if len(points) <= n:
        return np.arange(len(points))
    chosen = [int(np.argmax(np.linalg.norm(points - points.mean(axis=0), axis=1)))]
    gap = np.linalg.norm(points - points[chosen[0]], axis=1)
    for _ in range(n - 1):
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, np.linalg.norm(points - points[chosen[-1]], axis=1))
    return np.array(chosen)


def _hull(v: np.ndarray, k: int) -> trimesh.Trimesh:
    # trimesh divides by the volume when fixing a hull's orientation: silence that for flat pieces,
    # which are rejected just below.
    with np.errstate(invalid="ignore", divide="ignore"):
        try:
            hull = trimesh.convex.convex_hull(v)
        except Exception as exc:  # qhull raises its own error types for flat inputs
            raise MeshError(f"convex piece {k}: no 3-D convex hull ({exc})") from exc
        flat = not hull.volume > 0
    if flat:
        raise MeshError(f"convex piece {k}: zero volume")
    return hull


def vertices_to_pieces(vertices: list[np.ndarray]) -> ConvexPieces:
    """K vertex arrays (V_k, 3) m -> ConvexPieces, each piece replaced by its convex hull.

    Taking the hull makes any input safe for GJK/EPA (which need convex shapes) and leaves an already
    convex piece (the paper's, coacd's) unchanged. Raises MeshError for a flat or degenerate piece.
    """
    hulls_v, hulls_f, centers, radii, inner_v, inner_p = [], [], [], [], [], []
    for k, v in enumerate(vertices):
        v = np.asarray(v, dtype=np.float64)
        if v.ndim != 2 or v.shape[0] < 4 or v.shape[1] != 3:
            raise MeshError(f"convex piece {k}: need at least 4 points (V, 3), got shape {v.shape}")
        hull = _hull(v, k)
        center = (hull.vertices.max(axis=0) + hull.vertices.min(axis=0)) / 2
        hulls_v.append(np.asarray(hull.vertices))
        hulls_f.append(np.asarray(hull.faces))
        centers.append(center)
        radii.append(np.linalg.norm(hull.vertices - center, axis=1).max())
        subset = np.asarray(hull.vertices)[_spread_subset(np.asarray(hull.vertices), INNER_VERTICES)]
        try:
            inner = _hull(subset, k)
        except MeshError:  # the spread vertices happen to be coplanar: fall back to the whole hull
            inner = hull
        normals = np.asarray(inner.face_normals)
        planes = np.concatenate([normals, np.sum(normals * inner.vertices[inner.faces[:, 0]], axis=1)[:, None]], axis=1)
        inner_v.append(np.asarray(inner.vertices))
        inner_p.append(planes)
    return ConvexPieces(
        tuple(hulls_v), tuple(hulls_f), np.array(centers), np.array(radii), tuple(inner_v), tuple(inner_p)
    )


def box_point_distance(points: np.ndarray, half_extents: np.ndarray) -> np.ndarray:
    """(..., 3) points in a box's frame (box centred at 0) -> (...) distance to the box, 0 inside."""
    return np.linalg.norm(np.maximum(np.abs(points) - half_extents, 0.0), axis=-1)


def box_point_depth(points: np.ndarray, half_extents: np.ndarray) -> np.ndarray:
    """(..., 3) points in a box's frame -> (...) distance from each inside point to the box's surface, 0 outside."""
    return np.maximum(np.min(half_extents - np.abs(points), axis=-1), 0.0)


# Points of the DIGIT box, in its frame, whose depth inside a piece bounds the penetration: the 8
# corners and the 6 face centres.
_BOX_SAMPLES = np.concatenate(
    [
        np.array([[x, y, z] for x in (1, -1) for y in (1, -1) for z in (1, -1)], dtype=np.float64),
        np.concatenate([np.eye(3), -np.eye(3)]),
    ]
) * BOX_HALF_EXTENTS


class PenetrationModel:
    """fcl objects for an object's pieces and one DIGIT box, reused across queries."""

    def __init__(self, pieces: ConvexPieces):
        self.pieces = pieces
        self._piece_objects = []
        for v, f in zip(pieces.vertices, pieces.faces):
            flat = np.hstack([np.full((len(f), 1), 3), f]).ravel().astype(np.int64)
            self._piece_objects.append(fcl.CollisionObject(fcl.Convex(v, len(f), flat), fcl.Transform()))
        # The box sits at the origin of its own frame; pieces are posed relative to it.
        self._box = fcl.CollisionObject(fcl.Box(*(2.0 * BOX_HALF_EXTENTS)), fcl.Transform())
        self._request = fcl.CollisionRequest(num_max_contacts=1, enable_contact=True)

    def depth(self, piece: int, T_box_object: np.ndarray) -> float:
        """Penetration depth (m) of one piece at pose T_box_object (4, 4) into the box; 0 when apart."""
        obj = self._piece_objects[piece]
        obj.setTransform(fcl.Transform(T_box_object[:3, :3], T_box_object[:3, 3]))
        result = fcl.CollisionResult()
        if fcl.collide(obj, self._box, self._request, result) == 0:
            return 0.0
        return max(0.0, float(result.contacts[0].penetration_depth))


def sensor_box_poses(T_world_sensor: np.ndarray) -> np.ndarray:
    """(L, 4, 4) sensor poses -> (L, 4, 4) poses of their collision boxes' centres, ``T_world_box``."""
    return np.asarray(T_world_sensor, dtype=np.float64) @ make_pose(np.eye(3), BOX_CENTER)


def object_to_box_poses(T_world_object: np.ndarray, T_world_sensor: np.ndarray) -> np.ndarray:
    """T_world_object (P, 4, 4), T_world_sensor (L, 4, 4) -> (P, L, 4, 4): the object in each box's frame."""
    T_world_object = np.asarray(T_world_object, dtype=np.float64).reshape(-1, 4, 4)
    T_box_world = invert_pose(sensor_box_poses(T_world_sensor))
    return T_box_world[None] @ T_world_object[:, None]


def _near_pieces(pieces: ConvexPieces, relative: np.ndarray) -> np.ndarray:
    """relative (P, L, 4, 4) T_box_object -> (P, L, K) bool: piece k's bounding sphere meets the box."""
    R = relative[..., :3, :3]
    # One matrix multiply for all poses and pieces (an einsum here took 3 times as long with 32 pieces).
    centers = (R.reshape(-1, 3) @ pieces.centers.T).reshape(*R.shape[:-1], -1).swapaxes(-1, -2)
    centers = centers + relative[..., None, :3, 3]
    return box_point_distance(centers, BOX_HALF_EXTENTS) < pieces.radii


def _near_pairs(pieces: ConvexPieces, T_world_object: np.ndarray, T_world_sensor: np.ndarray, chunk: int = 8192):
    """Yield (k, p, i, R, t) for piece k and chunks of (pose p, sensor i) pairs whose bounding sphere
    meets the box, with R (n, 3, 3), t (n, 3) of T_box_object."""
    relative = object_to_box_poses(T_world_object, T_world_sensor)
    near = _near_pieces(pieces, relative)
    for k in range(len(pieces.vertices)):
        p_all, i_all = np.nonzero(near[:, :, k])
        for lo in range(0, len(p_all), chunk):
            p, i = p_all[lo : lo + chunk], i_all[lo : lo + chunk]
            yield k, p, i, relative[p, i, :3, :3], relative[p, i, :3, 3]


def poses_to_vertex_depth_bounds(pieces: ConvexPieces, T_world_object: np.ndarray, T_world_sensor: np.ndarray) -> np.ndarray:
    """Lower bounds on the penetration depths: (P, 4, 4), (L, 4, 4) -> (P, L) metres.

    A translation separating a piece from the box must carry every piece point out of the box, so the
    depth is at least that of the deepest inner-hull vertex inside the box. Cheap (one matrix multiply
    per chunk); 0 when the object's face, not its corner, is in the box: see the next bound.
    """
    bounds = np.zeros((np.asarray(T_world_object).reshape(-1, 4, 4).shape[0], np.asarray(T_world_sensor).reshape(-1, 4, 4).shape[0]))
    for k, p, i, R, t in _near_pairs(pieces, T_world_object, T_world_sensor):
        v = pieces.inner_vertices[k]
        v_box = (R.reshape(-1, 3) @ v.T).reshape(len(p), 3, -1) + t[:, :, None]  # (n, 3, V)
        depth = np.maximum(np.min(BOX_HALF_EXTENTS[None, :, None] - np.abs(v_box), axis=1), 0.0).max(axis=1)
        bounds[p, i] = np.maximum(bounds[p, i], depth)
    return bounds


def poses_to_box_depth_bounds(pieces: ConvexPieces, T_world_object: np.ndarray, T_world_sensor: np.ndarray) -> np.ndarray:
    """Lower bounds on the penetration depths: (P, 4, 4), (L, 4, 4) -> (P, L) metres.

    A separating translation must also carry every box point out of the piece, so the depth is at
    least that of the deepest box sample (corner, face centre) inside the piece's inner hull (which
    lies inside the piece, so depths in it are no larger). Costs samples x planes per pair.
    """
    bounds = np.zeros((np.asarray(T_world_object).reshape(-1, 4, 4).shape[0], np.asarray(T_world_sensor).reshape(-1, 4, 4).shape[0]))
    for k, p, i, R, t in _near_pairs(pieces, T_world_object, T_world_sensor):
        planes = pieces.inner_planes[k]
        Rt = R.transpose(0, 2, 1)
        # Box samples in the object frame, R^T (x - t), one matrix multiply for the chunk.
        samples = (np.ascontiguousarray(Rt).reshape(-1, 3) @ _BOX_SAMPLES.T).reshape(len(p), 3, -1) - Rt @ t[:, :, None]
        samples = samples.transpose(0, 2, 1).reshape(-1, 3)
        inside = (planes[:, 3] - samples @ planes[:, :3].T).min(axis=1).reshape(len(p), -1)
        bounds[p, i] = np.maximum(bounds[p, i], np.maximum(inside, 0.0).max(axis=1))
    return bounds


def poses_to_fcl_depths(model: PenetrationModel, T_world_object: np.ndarray, T_world_sensor: np.ndarray) -> np.ndarray:
    """fcl's penetration depths alone: (P, 4, 4), (L, 4, 4) -> (P, L) metres, the largest over pieces; 0
    where apart. EPA can stop short on some contacts: ``poses_to_penetrations`` raises these to the
    lower bounds, and so does ``rank.rank_poses`` with the bounds it has already computed.
    """
    relative = object_to_box_poses(T_world_object, T_world_sensor)
    near = _near_pieces(model.pieces, relative)
    depths = np.zeros(near.shape)
    for p, i, k in zip(*np.nonzero(near)):
        depths[p, i, k] = model.depth(k, relative[p, i])
    return depths.max(axis=2) if depths.shape[2] else np.zeros(near.shape[:2])


def poses_to_penetrations(model: PenetrationModel, T_world_object: np.ndarray, T_world_sensor: np.ndarray) -> np.ndarray:
    """Penetration depth of the object at each pose into each sensor's box.

    model: PenetrationModel of the object's pieces; T_world_object (P, 4, 4); T_world_sensor (L, 4, 4)
    -> (P, L) metres: fcl's depth (``poses_to_fcl_depths``), raised to the two lower bounds
    (``poses_to_vertex_depth_bounds``, ``poses_to_box_depth_bounds``) where EPA stops short of them;
    0 where apart.
    """
    bounds = np.maximum(
        poses_to_vertex_depth_bounds(model.pieces, T_world_object, T_world_sensor),
        poses_to_box_depth_bounds(model.pieces, T_world_object, T_world_sensor),
    )
    return np.maximum(poses_to_fcl_depths(model, T_world_object, T_world_sensor), bounds)
