"""Contact types (flat, edge, corner, curved) and the contact-accuracy metric (docs/design.md, The metrics).

The classifier looks at the object's surface within a ball about the size of a DIGIT gel around the
contact, through a dense, fixed sample of the surface with face normals (``SurfaceSamples``, built
once per mesh). The rule, applied in this order (``ContactRule`` holds the thresholds):

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
from scipy.spatial import cKDTree

from tactile6d.geometry import invert_pose, transform_points
from tactile6d.sensor import contact_normals, contact_points

CONTACT_TYPES = ("flat", "edge", "corner", "curved")
FLAT, EDGE, CORNER, CURVED = range(4)
NO_SURFACE = -1  # no surface facing the sensor near the point (e.g. a wrong pose puts it behind the object)

CONTACT_TOLERANCE = 0.003  # metres: the largest gap or penetration of a sensor that still counts as touching
FACING_MAX_DEG = 60.0  # the gel faces the surface if some surface near the contact is this close to its normal

# Points per winding-number batch: bounds the temporary (points x triangles x 3 x 3) arrays (~40 MB for 16k faces).
_WINDING_BATCH = 24


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


def _as_samples(surface: SurfaceSamples | trimesh.Trimesh) -> SurfaceSamples:
    return surface if isinstance(surface, SurfaceSamples) else sample_surface(surface)


def _unit(v: np.ndarray) -> np.ndarray:
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
        centre = _unit(normals[close[seed] & left].mean(axis=0))
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
    samples = _as_samples(surface)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = _unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
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
    """
    tris = np.asarray(mesh.triangles, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(points))
    for start in range(0, len(points), _WINDING_BATCH):
        rel = tris[None] - points[start : start + _WINDING_BATCH, None, None, :]  # (b, F, 3, 3)
        a, b, c = rel[..., 0, :], rel[..., 1, :], rel[..., 2, :]
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.sum(a * np.cross(b, c), axis=-1)
        den = la * lb * lc + np.sum(a * b, -1) * lc + np.sum(b * c, -1) * la + np.sum(c * a, -1) * lb
        out[start : start + _WINDING_BATCH] = np.sum(np.arctan2(det, den), axis=-1) / (2.0 * np.pi)
    return out


def signed_distances(mesh: trimesh.Trimesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (n,) metres from points (n, 3) to the surface, positive outside, and the nearest
    surface points (n, 3). The sign comes from the winding number (inside when above 1/2)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    nearest, distance, _ = mesh.nearest.on_surface(points)
    inside = winding_numbers(mesh, points) > 0.5
    return np.where(inside, -distance, distance), nearest


def _faces_surface(samples: SurfaceSamples, points: np.ndarray, normals: np.ndarray, rule: ContactRule) -> np.ndarray:
    """Whether some surface within ``rule.core_radius`` of each point (n, 3) has its normal within
    ``FACING_MAX_DEG`` of the sensor's normal (n, 3): (n,) bool. At an edge the nearest triangle may
    belong to the face the sensor does not press, so every normal near the contact is considered."""
    cos_max = np.cos(np.radians(FACING_MAX_DEG))
    out = np.zeros(len(points), dtype=bool)
    for i, idx in enumerate(samples.tree.query_ball_point(points, rule.core_radius)):
        out[i] = len(idx) > 0 and bool(np.max(samples.normals[idx] @ normals[i]) >= cos_max)
    return out


def _sensor_contacts_in_object(
    T_world_object: np.ndarray, T_world_sensors: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Contact points and approach normals of L sensors in the frame of K object poses: (K, L, 3) each."""
    T_object_world = invert_pose(T_world_object)  # (K, 4, 4)
    points = transform_points(T_object_world, contact_points(T_world_sensors))  # (K, L, 3)
    normals = contact_normals(T_world_sensors) @ np.swapaxes(T_object_world[:, :3, :3], -1, -2)
    return points, normals


def contact_accuracy(
    surface: SurfaceSamples | trimesh.Trimesh,
    T_world_object_est: np.ndarray,
    T_world_object_gt: np.ndarray,
    T_world_sensors: np.ndarray,
    tolerance: float = CONTACT_TOLERANCE,
    rule: ContactRule = ContactRule(),
) -> dict[str, np.ndarray]:
    """Contact accuracy of K estimates of one scene: T_est (K, 4, 4), T_gt (4, 4), sensors (L, 4, 4).

    An estimate is correct when, for **every** sensor i (contact point c_i = ``contact_points``,
    approach normal n_i = ``contact_normals``, both moved into the object frame of each pose):
    - it touches the object at the estimated pose: the signed distance from c_i to the surface
      (positive outside) lies in ``[-tolerance, +tolerance]`` (3 mm of gap or of penetration), and
      the gel faces the surface there (some surface within ``rule.core_radius`` of the nearest point
      has its normal within ``FACING_MAX_DEG`` of n_i);
    - on a surface of the same kind as in reality: ``classify_contacts`` gives the same type at c_i's
      nearest surface point at the estimated pose as at the true pose.

    Returns a dict: ``correct`` (K,) bool; per estimate and sensor (K, L): ``signed_distance`` (m),
    ``facing`` (bool), ``touching`` (bool), ``type_est`` (int codes), ``same_type`` (bool); and
    ``type_true`` (L,) int codes.
    """
    samples = _as_samples(surface)
    T_est = np.asarray(T_world_object_est, dtype=np.float64).reshape(-1, 4, 4)
    T_gt = np.asarray(T_world_object_gt, dtype=np.float64).reshape(1, 4, 4)
    T_sensors = np.asarray(T_world_sensors, dtype=np.float64).reshape(-1, 4, 4)
    K, L = len(T_est), len(T_sensors)

    true_points, true_normals = _sensor_contacts_in_object(T_gt, T_sensors)
    type_true = classify_contacts(samples, true_points[0], true_normals[0], rule)

    points, normals = (a.reshape(K * L, 3) for a in _sensor_contacts_in_object(T_est, T_sensors))
    signed, nearest = signed_distances(samples.mesh, points)
    facing = _faces_surface(samples, nearest, _unit(normals), rule)
    type_est = classify_contacts(samples, points, normals, rule)

    signed, facing, type_est = (a.reshape(K, L) for a in (signed, facing, type_est))
    touching = (np.abs(signed) <= tolerance) & facing
    same_type = type_est == type_true[None, :]
    return {
        "correct": np.all(touching & same_type, axis=1),
        "signed_distance": signed,
        "facing": facing,
        "touching": touching,
        "type_est": type_est,
        "same_type": same_type,
        "type_true": type_true,
    }


def contact_accuracy_single(
    surface: SurfaceSamples | trimesh.Trimesh,
    T_world_object_est: np.ndarray,
    T_world_object_gt: np.ndarray,
    T_world_sensors: np.ndarray,
    tolerance: float = CONTACT_TOLERANCE,
    rule: ContactRule = ContactRule(),
) -> tuple[bool, dict[str, np.ndarray]]:
    """One estimate (4, 4): ``(correct, details)`` with the per-sensor (L,) arrays of ``contact_accuracy``
    and the type names ``type_est_names`` / ``type_true_names``."""
    result = contact_accuracy(surface, T_world_object_est, T_world_object_gt, T_world_sensors, tolerance, rule)
    details = {key: value[0] for key, value in result.items() if key not in ("correct", "type_true")}
    details["type_true"] = result["type_true"]
    details["type_est_names"] = contact_type_names(details["type_est"])
    details["type_true_names"] = contact_type_names(result["type_true"])
    return bool(result["correct"][0]), details
