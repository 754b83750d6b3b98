"""Points on a mesh surface, with outward normals: evenly spread (the database's points), or dense and
fixed with a search tree (``SurfaceSamples``: the contact-type classifier and the refinement read those).

Method: draw many area-weighted random points on the triangles (``oversample`` per kept point),
then keep ``M`` of them by farthest-point sampling, which greedily adds the candidate farthest from
all points kept so far. The result is Poisson-disk-like: no two points closer than the final
insertion distance, and no gap wider than it. Distances are Euclidean, which is what the
distance-based selection compares.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree


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
    d, _ = cKDTree(points).query(points, k=2)
    return d[:, 1]


@dataclass(frozen=True)
class SurfaceSamples:
    """A mesh with a dense fixed sample of its surface: points (S, 3), unit face normals (S, 3), a tree."""

    mesh: trimesh.Trimesh
    points: np.ndarray
    normals: np.ndarray
    tree: cKDTree


def sample_surface(mesh: trimesh.Trimesh, spacing: float = 0.001, seed: int = 0) -> SurfaceSamples:
    """Precompute the classifier's view of a mesh: about one sample per ``spacing``^2 of area.

    The samples are area-uniform and fixed by ``seed``, so the same mesh always gets the same labels.
    At 1 mm spacing a ball of 8 mm radius holds ~200 samples on a flat face.
    """
    count = max(1000, int(np.ceil(mesh.area / spacing**2)))
    points, faces = trimesh.sample.sample_surface(mesh, count, seed=seed)
    normals = np.asarray(mesh.face_normals[faces], dtype=np.float64)
    return SurfaceSamples(mesh, np.asarray(points, dtype=np.float64), normals, cKDTree(points))


def as_surface_samples(surface: SurfaceSamples | trimesh.Trimesh) -> SurfaceSamples:
    return surface if isinstance(surface, SurfaceSamples) else sample_surface(surface)
