"""The contact-accuracy metric (docs/design.md, The metrics): does an estimate make every sensor touch the
object, on the same kind of surface (``contact_types``) as the true pose does?"""

from __future__ import annotations

import numpy as np
import trimesh

from tactile6d.core.geometry import invert_pose, transform_points
from tactile6d.core.sensor import contact_normals, contact_points
from tactile6d.sim.contact_types import ContactRule, classify_contacts, contact_type_names, signed_distances, unit
from tactile6d.sim.surface_sampling import SurfaceSamples, as_surface_samples

CONTACT_TOLERANCE = 0.003  # metres: the largest gap or penetration of a sensor that still counts as touching
FACING_MAX_DEG = 60.0  # the gel faces the surface if some surface near the contact is this close to its normal


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
    samples = as_surface_samples(surface)
    T_est = np.asarray(T_world_object_est, dtype=np.float64).reshape(-1, 4, 4)
    T_gt = np.asarray(T_world_object_gt, dtype=np.float64).reshape(1, 4, 4)
    T_sensors = np.asarray(T_world_sensors, dtype=np.float64).reshape(-1, 4, 4)
    K, L = len(T_est), len(T_sensors)

    true_points, true_normals = _sensor_contacts_in_object(T_gt, T_sensors)
    type_true = classify_contacts(samples, true_points[0], true_normals[0], rule)

    points, normals = (a.reshape(K * L, 3) for a in _sensor_contacts_in_object(T_est, T_sensors))
    signed, nearest = signed_distances(samples.mesh, points)
    facing = _faces_surface(samples, nearest, unit(normals), rule)
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


def accuracy_to_details(result: dict[str, np.ndarray], k: int = 0) -> tuple[bool, dict[str, np.ndarray]]:
    """One estimate of a ``contact_accuracy`` result: ``(correct, details)`` with its per-sensor (L,) arrays,
    ``type_true`` and the type names ``type_est_names`` / ``type_true_names``."""
    details = {key: value[k] for key, value in result.items() if key not in ("correct", "type_true")}
    details["type_true"] = result["type_true"]
    details["type_est_names"] = contact_type_names(details["type_est"])
    details["type_true_names"] = contact_type_names(result["type_true"])
    return bool(result["correct"][k]), details
