"""Contact types (flat, edge, corner, curved): what kind of surface a sensor presses (docs/design.md, The metrics).

The classifier looks at the object's surface within a ball about the size of a DIGIT gel around the
contact, through a dense, fixed sample of the surface with face normals (``SurfaceSamples``, built
once per mesh, ``surface_sampling.sample_surface``). The rule, applied in this order (``ContactRule`` holds the thresholds):

1. Neighbourhood: surface samples within ``radius`` (8 mm) of the contact's nearest surface point,
   ignoring surface whose normal turns more than ``backface_deg`` (100 deg) away from the sensor's
   approach normal (the far side of thin parts, which the gel cannot press). Faces perpendicular to
   the approach are kept: a crease within reach of the gel belongs to the contact.
2. corner: the normals bend in two independent directions: the smallest eigenvalue of their second
   moment matrix ``mean(n n^T)``, read as an angle ``arcsin(sqrt(lambda_min))``, is at least
   ``corner_min_deg`` (18 deg). (An exact cube corner gives 35 deg, an edge ~0, a 4 cm sphere 6 deg;
   a rounded tip much smaller than the gel, e.g. a marker's end, also counts as a corner.)
3. edge: either the neighbourhood holds two planar facets meeting at a crease, or the surface bends
   sharply right at the contact. A facet is a greedy cluster of normals within ``facet_tolerance_deg``
   (7 deg) of its mean, holding at least ``facet_min_share`` (10 %) of the neighbourhood, spread over
   at least ``facet_min_spread`` (1.2 mm, standard deviation of its points across their narrow
   direction; on a curved surface a 7-deg band is a thin strip), and at least ``crease_min_deg``
   (30 deg) away from every larger facet. "Bends sharply" = the 90th percentile of the angle between
   the normals within ``core_radius`` (3 mm) and their mean is at least ``sharp_min_deg`` (25 deg):
   rolled rims and rounded box edges whose second face is mostly out of reach.
4. flat: the 90th percentile of the angle between the neighbourhood's normals and their mean is below
   ``flat_max_deg`` (5 deg): above the decimated YCB scans' flat faces, below a can's side (figures:
   docs/design.md, The metrics).
5. curved: everything else (cylinders, spheres, bottles: a smooth spread of normals without creases).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from tactile6d.sim.surface_sampling import SurfaceSamples, as_surface_samples

CONTACT_TYPES = ("flat", "edge", "corner", "curved")
FLAT, EDGE, CORNER, CURVED = range(4)
NO_SURFACE = -1  # no surface facing the sensor near the point (e.g. a wrong pose puts it behind the object)


@dataclass(frozen=True)
class ContactRule:
    """The classifier's thresholds (lengths in metres, angles in degrees); see the module docstring."""

    radius: float = 0.008
    core_radius: float = 0.003
    backface_deg: float = 100.0
    corner_min_deg: float = 18.0
    facet_tolerance_deg: float = 7.0
    facet_min_share: float = 0.10
    facet_min_spread: float = 0.0012
    crease_min_deg: float = 30.0
    sharp_min_deg: float = 25.0
    flat_max_deg: float = 5.0


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _p90_deviation_deg(normals: np.ndarray) -> float:
    """90th percentile of the angle (deg) between unit normals (k, 3) and their mean direction."""
    mean = np.sum(normals, axis=0)
    norm = np.linalg.norm(mean)
    if norm < 1e-9:  # normals cancel out: as spread as they get
        return 180.0
    cos = np.clip(normals @ (mean / norm), -1.0, 1.0)
    return float(np.degrees(np.arccos(np.percentile(cos, 10))))


def _out_of_plane_deg(normals: np.ndarray) -> float:
    """How far unit normals (k, 3) leave their best-fitting great circle: arcsin(sqrt(lambda_min)), deg."""
    lam = np.linalg.eigvalsh(normals.T @ normals / len(normals))[0]
    return float(np.degrees(np.arcsin(np.sqrt(np.clip(lam, 0.0, 1.0)))))


def _count_facets(points: np.ndarray, normals: np.ndarray, rule: ContactRule) -> int:
    """Planar facets at least ``crease_min_deg`` apart among neighbourhood samples (k, 3), (k, 3)."""
    cos_tol = np.cos(np.radians(rule.facet_tolerance_deg))
    cos_crease = np.cos(np.radians(rule.crease_min_deg))
    min_count = rule.facet_min_share * len(normals)
    close = normals @ normals.T > cos_tol  # (k, k): which normals lie within tolerance of which
    left = np.ones(len(normals), dtype=bool)
    facets: list[np.ndarray] = []
    while left.sum() >= min_count:
        # Seed at the normal with the most unclaimed neighbours, then re-collect around the cluster
        # mean so the facet does not depend on one noisy seed normal.
        seed = np.argmax(np.where(left, close[:, left].sum(axis=1), -1))
        centre = unit(normals[close[seed] & left].mean(axis=0))
        members = left & (normals @ centre > cos_tol)
        if members.sum() < min_count:
            break
        left &= ~members
        spread = points[members] - points[members].mean(axis=0)
        narrow = np.sqrt(max(np.linalg.eigvalsh(spread.T @ spread / members.sum())[1], 0.0))
        if narrow >= rule.facet_min_spread and all(centre @ f < cos_crease for f in facets):
            facets.append(centre)
    return len(facets)


def _classify_one(samples: SurfaceSamples, point: np.ndarray, normal: np.ndarray, rule: ContactRule) -> int:
    idx = np.asarray(samples.tree.query_ball_point(point, rule.radius), dtype=np.int64)
    normals = samples.normals[idx]
    front = normals @ normal > np.cos(np.radians(rule.backface_deg))
    normals, points = normals[front], samples.points[idx[front]]
    if len(normals) < 3:
        return NO_SURFACE
    if _out_of_plane_deg(normals) >= rule.corner_min_deg:
        return CORNER
    if _count_facets(points, normals, rule) >= 2:
        return EDGE
    core = np.linalg.norm(points - point, axis=1) <= rule.core_radius
    if core.sum() >= 3 and _p90_deviation_deg(normals[core]) >= rule.sharp_min_deg:
        return EDGE
    return FLAT if _p90_deviation_deg(normals) < rule.flat_max_deg else CURVED


def classify_contacts(
    surface: SurfaceSamples | trimesh.Trimesh,
    points: np.ndarray,
    normals: np.ndarray,
    rule: ContactRule = ContactRule(),
) -> np.ndarray:
    """Contact type codes (n,) int (indices into ``CONTACT_TYPES``, or ``NO_SURFACE`` where no surface
    within the neighbourhood faces the sensor), in the mesh's frame.

    points (n, 3): contact locations, snapped here to their nearest surface point; normals (n, 3):
    the sensor's approach direction as an outward surface normal (``sensor.contact_normals``).
    Pass ``sample_surface(mesh)`` to reuse the precomputation across calls. The rule is the module's.
    """
    samples = as_surface_samples(surface)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    on_surface, _, _ = samples.mesh.nearest.on_surface(points)
    return np.array([_classify_one(samples, p, n, rule) for p, n in zip(on_surface, normals)], dtype=np.int64)


def sharpness_ranks(codes: np.ndarray) -> np.ndarray:
    """Contact type codes (...) -> int64 (...): how sharply the surface bends under the gel, as a rank:
    flat 0, edge 1, corner 2; curved and ``NO_SURFACE`` -1, unranked (a curve may bend more gently or more
    sharply than an edge). The autoencoder's ranking loss orders latent angles by it."""
    return np.array([0, 1, 2, -1, -1], dtype=np.int64)[np.where(np.asarray(codes) == NO_SURFACE, 4, codes)]


def contact_type_names(codes: np.ndarray) -> np.ndarray:
    """Codes (...) -> names (...) from ``CONTACT_TYPES``; ``NO_SURFACE`` -> "none"."""
    codes = np.asarray(codes)
    return np.where(codes == NO_SURFACE, "none", np.asarray(CONTACT_TYPES)[np.clip(codes, 0, None)])


def winding_numbers(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Generalised winding number of a triangle mesh at points (n, 3) -> (n,): ~1 inside, ~0 outside.

    Sum over triangles of their signed solid angle seen from the point, over 4 pi (Van Oosterom &
    Strackee's formula). Unlike ray parity it degrades gracefully on meshes with small holes, such
    as 040_large_marker.

    One point at a time over contiguous (F,) planes of the triangles' vertex coordinates: ten times
    faster than strided (n, F, 3, 3) arrays through ``np.cross`` and ``np.linalg.norm``, and the same bits,
    since every sum of three terms is added in their order, ``(x + y) + z`` (the test compares the two).
    """
    tris = np.asarray(mesh.triangles, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    planes = [[np.ascontiguousarray(tris[:, v, k]) for k in range(3)] for v in range(3)]
    out = np.empty(len(points))
    for i, p in enumerate(points):
        a, b, c = ([plane - p[k] for k, plane in enumerate(vertex)] for vertex in planes)
        la, lb, lc = (np.sqrt((v[0] * v[0] + v[1] * v[1]) + v[2] * v[2]) for v in (a, b, c))
        det = (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])) + a[2] * (b[0] * c[1] - b[1] * c[0])
        ab = (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
        bc = (b[0] * c[0] + b[1] * c[1]) + b[2] * c[2]
        ca = (c[0] * a[0] + c[1] * a[1]) + c[2] * a[2]
        out[i] = np.sum(np.arctan2(det, la * lb * lc + ab * lc + bc * la + ca * lb)) / (2.0 * np.pi)
    return out


def signed_distances(mesh: trimesh.Trimesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (n,) metres from points (n, 3) to the surface, positive outside, and the nearest
    surface points (n, 3). The sign comes from the winding number (inside when above 1/2)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    nearest, distance, _ = mesh.nearest.on_surface(points)
    inside = winding_numbers(mesh, points) > 0.5
    return np.where(inside, -distance, distance), nearest
