"""Is a wrong estimate a pose the contacts cannot tell from the truth? Near-symmetries of the object.

A tactile estimate sees the object only where the sensors touch it. Two poses whose surfaces coincide there
are the same to every image and every contact, however far apart their origins lie: a box turned 180 deg
about one of its axes, a pitcher turned about its body's axis (the origin, off that axis, then moves by
``2 r sin(angle / 2)``). The positional error ``||t_est - t_gt||`` counts those turns in full, the ADI
hardly at all. This module measures, for an estimate and the truth, how much of the object's surface the
one pose puts where the other has it:

- over the whole surface (``surface_share``): near 1, the turn is a near-symmetry of the object itself and
  no contact anywhere would tell the two apart;
- over the surface near the contacts (``contact_share``, true contact points within ``radius``): near 1,
  the two are alike where the sensors touched, so these contacts cannot tell them apart, whatever a touch
  elsewhere could.

``confusion_kind`` names the case. A diagnostic for the evaluation (``scripts/symmetric_confusions.py``): the
estimator uses none of it.
"""

from __future__ import annotations

import numpy as np
import trimesh

from tactile6d.core.geometry import invert_pose, transform_points

SURFACE_TOL = 0.001  # m: a point this near the surface lies on it (the contacts' own reading error is 0.5 mm)
CONTACT_RADIUS = 0.02  # m: the surface "where touched": within this of a contact (a DIGIT gel is 19 x 25 mm)
ALIKE_SHARE = 0.9  # share of the surface on the surface for two poses to count as alike there
KINDS = ("object symmetry", "alike where touched", "other")


def surface_samples(mesh: trimesh.Trimesh, n: int = 2000, seed: int = 0) -> np.ndarray:
    """n points (n, 3) drawn uniformly over the mesh's surface, object frame, the same for the same seed."""
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points, dtype=np.float64)


def relative_pose(T_estimate: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """The estimate in the true object's frame (4, 4): the object's point x sits at T_estimate x in the world,
    which is T_true (D x) with D = T_true^-1 T_estimate; D = I for the true pose."""
    return invert_pose(np.asarray(T_true, dtype=np.float64)) @ np.asarray(T_estimate, dtype=np.float64)


def on_surface(mesh: trimesh.Trimesh, points: np.ndarray, tol: float = SURFACE_TOL) -> np.ndarray:
    """(N,) bool: which of points (N, 3), object frame, lie within tol (m) of the mesh's surface."""
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    _, distance, _ = trimesh.proximity.closest_point(mesh, np.asarray(points, dtype=np.float64))
    return np.asarray(distance) <= tol


def covered_share(mesh: trimesh.Trimesh, points: np.ndarray, D: np.ndarray, tol: float = SURFACE_TOL) -> float:
    """Share of the true surface's points (N, 3), object frame, that the surface of the object placed at D
    (``relative_pose``) passes within tol of: D^-1 carries each point into the placed object's own frame,
    where it lies on the mesh exactly when the placed surface goes through it. NaN for no points."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return float("nan")
    return float(on_surface(mesh, transform_points(invert_pose(D), points), tol).mean())


def surface_share(mesh: trimesh.Trimesh, samples: np.ndarray, D: np.ndarray, tol: float = SURFACE_TOL) -> float:
    """``covered_share`` over the whole surface (samples from ``surface_samples``): 1 for a symmetry of the
    object (a box's 180 deg turns about its axes), small for a pose that puts the object elsewhere."""
    return covered_share(mesh, samples, D, tol)


def contact_share(mesh: trimesh.Trimesh, samples: np.ndarray, D: np.ndarray, contacts: np.ndarray,
                  radius: float = CONTACT_RADIUS, tol: float = SURFACE_TOL) -> float:
    """``covered_share`` over the samples within radius (m) of any of contacts (L, 3), the true contact points
    in the object's frame: 1 when both poses have the same surface where the sensors touched."""
    samples = np.asarray(samples, dtype=np.float64)
    contacts = np.asarray(contacts, dtype=np.float64).reshape(-1, 3)
    near = np.min(np.linalg.norm(samples[:, None] - contacts[None], axis=-1), axis=1) <= radius
    return covered_share(mesh, samples[near], D, tol)


def confusion_kind(surface: float, at_contacts: float, alike: float = ALIKE_SHARE) -> str:
    """One of ``KINDS`` from the two shares: "object symmetry" when the whole surfaces coincide (at least
    ``alike`` of it), "alike where touched" when only the touched surface does, else "other"."""
    if surface >= alike:
        return KINDS[0]
    if at_contacts >= alike:
        return KINDS[1]
    return KINDS[2]
