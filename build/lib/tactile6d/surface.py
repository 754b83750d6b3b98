"""Evenly spread points on a mesh surface, with outward normals.

Method: draw many area-weighted random points on the triangles (``oversample`` per kept point),
then keep ``M`` of them by farthest-point sampling, which greedily adds the candidate farthest from
all points kept so far. The result is Poisson-disk-like: no two points closer than the final
insertion distance, and no gap wider than it. Distances are Euclidean, which is what the
distance-based selection compares.
"""

from __future__ import annotations

import numpy as np
import trimesh


def sample_surface_random(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """n area-weighted uniform points on the surface -> points (n, 3), face index (n,)."""
    areas = mesh.area_faces
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    u, v = rng.random((2, n))
    flip = u + v > 1.0  # reflect into the triangle so the barycentric weights stay uniform
    u, v = np.where(flip, 1.0 - u, u), np.where(flip, 1.0 - v, v)
    tri = mesh.triangles[face]
    points = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    return points, face


def farthest_point_sampling(points: np.ndarray, m: int, first: int = 0) -> np.ndarray:
    """(n, 3) -> (m,) indices chosen greedily, each the farthest from those chosen before it."""
    n = len(points)
    if m > n:
        raise ValueError(f"cannot pick {m} of {n} points")
    chosen = np.empty(m, dtype=np.int64)
    chosen[0] = first
    dist = np.sum((points - points[first]) ** 2, axis=1)
    for k in range(1, m):
        chosen[k] = int(np.argmax(dist))
        np.minimum(dist, np.sum((points - points[chosen[k]]) ** 2, axis=1), out=dist)
    return chosen


def sample_surface_even(
    mesh: trimesh.Trimesh, m: int, rng: np.random.Generator, oversample: int = 30
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """M evenly spread surface points -> points (M, 3), outward unit normals (M, 3), face index (M,).

    The normal of a point is its triangle's normal (the mesh must be wound outward, as
    ``meshes.clean_mesh`` leaves it).
    """
    candidates, faces = sample_surface_random(mesh, m * oversample, rng)
    keep = farthest_point_sampling(candidates, m, first=int(rng.integers(len(candidates))))
    normals = np.asarray(mesh.face_normals[faces[keep]], dtype=np.float64)
    return candidates[keep], normals, faces[keep]


def nearest_neighbour_distances(points: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n,): each point's distance to its nearest other point."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points, k=2)
    return d[:, 1]
