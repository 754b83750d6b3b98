"""How well could any estimator place the object when the sensor poses it is given are off? A lower bound.

A robot reports each sensor pose through its kinematics, off by a small error ``E_i`` in the sensor's own
frame (``T_reported = T_true @ E_i``, as ``sim.perturb.perturb_sensor_poses`` draws it: a translation and a
rotation vector, Gaussian, ``sigma_m`` and ``sigma_rad`` per axis). The images are those of the true poses,
so at best they tell each sensor's pose *relative to the object*, ``T_io = inv(T_wi) @ T_wo``, exactly.
An *oracle* that knows those relative poses still has to place the object in the world through the
reported poses: sensor i says the object is at ``T_reported_i @ T_io``, off the truth by

    position  R_wi (t_i + (R(w_i) - I) p_io)  ~  R_wi t_i - R_wi [p_io]x w_i
    rotation  R_wi w_i                          (world frame, left)

with ``p_io`` the object's origin in sensor i's frame: a sensor's rotation error moves the object by its
lever arm. Each sensor is so one Gaussian reading of the object's pose, covariance ``C_i = A_i S A_i^T``
(``A_i`` the 6 x 6 matrix above, ``S = diag(sigma_m^2 I, sigma_rad^2 I)``); the best any estimator can do
with them (flat prior on the object's pose: its minimum-variance estimate, which for a Gaussian posterior
also minimises the expected norm of the position error, Anderson's lemma) is their information-weighted
mean, whose error covariance is ``inv(sum_i inv(C_i))``.

No estimator that reads the images can beat this oracle: the images carry at most the relative poses it is
given. Hence the *bound* on a scene set: each scene's expected positional error under that covariance, and
the oracle's realised error for the errors the set drew. Vectors are ordered (position m, rotation rad);
poses 4x4 float64.
"""

from __future__ import annotations

import numpy as np

from tactile6d.core.geometry import invert_pose, make_pose, rotmat_to_rotvec, rotvec_to_rotmat, skew


def true_sensor_poses(scenes, s: int) -> np.ndarray | None:
    """Scene s's true sensor poses (L, 4, 4) when its set stored the errors ``sim.perturb.perturb_sensor_poses``
    added (``T_reported = T_true @ error``, the error in the sensor's frame), else None. scenes: the scene
    artifact's datasets (``read_artifact(..., "scenes")``) or ``SceneSet.as_datasets()``."""
    if "pose_error_translation" not in scenes:
        return None
    error = make_pose(rotvec_to_rotmat(np.asarray(scenes["pose_error_rotvec"][s])),
                      np.asarray(scenes["pose_error_translation"][s]))
    return np.asarray(scenes["T_world_sensors"][s]) @ invert_pose(error)


def seen_through_true_errors(T_world_object: np.ndarray, T_reported: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """The object (4, 4) as each sensor sees it through its reported pose (L, 4, 4) when its correction is the
    sensor's true error (T_true (L, 4, 4)) -> (L, 4, 4) ``T_reported_i inv(T_true_i) T_world_object``: the pose
    whose relative pose to the reported sensor is the true one, ``inv(T_reported_i) seen_i = inv(T_true_i)
    T_world_object`` (the ``seen`` of ``refine.refine_poses_and_sensors``, with the corrections an oracle knows)."""
    T_reported, T_true = np.asarray(T_reported, dtype=np.float64), np.asarray(T_true, dtype=np.float64)
    return np.stack([T_reported[i] @ invert_pose(T_true[i]) @ np.asarray(T_world_object) for i in range(len(T_true))])


def poses_to_object_jacobians(T_world_object: np.ndarray, T_world_sensors: np.ndarray) -> np.ndarray:
    """(4, 4), (L, 4, 4) true poses -> (L, 6, 6): each sensor's frame error (t, w) to the error of the object
    pose it implies (world position, world rotation vector), to first order (module docstring)."""
    T_os = np.asarray(T_world_sensors, dtype=np.float64)
    R = T_os[:, :3, :3]
    p_io = np.einsum("lji,lj->li", R, np.asarray(T_world_object)[:3, 3] - T_os[:, :3, 3])  # R^T (p_wo - p_wi)
    A = np.zeros((len(T_os), 6, 6))
    A[:, :3, :3] = R
    A[:, :3, 3:] = -R @ skew(p_io)
    A[:, 3:, 3:] = R
    return A


def implied_object_errors(T_world_object: np.ndarray, T_world_sensors: np.ndarray,
                          T_world_sensors_reported: np.ndarray) -> np.ndarray:
    """(4, 4), (L, 4, 4), (L, 4, 4) -> (L, 6): the error of the object pose each sensor implies when its
    pose relative to the object is known exactly (``T_reported_i @ inv(T_i) @ T_wo`` against ``T_wo``):
    position (m) and rotation vector (rad), world frame. Exact, not linearised."""
    T_wo = np.asarray(T_world_object, dtype=np.float64)
    implied = np.asarray(T_world_sensors_reported) @ invert_pose(np.asarray(T_world_sensors)) @ T_wo
    position = implied[:, :3, 3] - T_wo[:3, 3]
    rotation = rotmat_to_rotvec(implied[:, :3, :3] @ T_wo[:3, :3].T)
    return np.concatenate([position, rotation], axis=1)


def sensor_covariances(jacobians: np.ndarray, sigma_m: float, sigma_rad: float) -> np.ndarray:
    """(L, 6, 6) ``poses_to_object_jacobians`` and the per-axis sigmas -> (L, 6, 6): the covariance of the
    object pose error each sensor implies, ``A S A^T``."""
    S = np.diag([sigma_m**2] * 3 + [sigma_rad**2] * 3)
    return jacobians @ S @ np.swapaxes(jacobians, 1, 2)


def fuse_object_errors(errors: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(L, 6) per-sensor errors, (L, 6, 6) their covariances -> the information-weighted mean's error (6,)
    and its covariance (6, 6): ``P = inv(sum inv(C_i))``, ``e = P sum inv(C_i) e_i``."""
    information = np.linalg.inv(covariances)
    P = np.linalg.inv(information.sum(axis=0))
    P = 0.5 * (P + P.T)
    return P @ np.einsum("lij,lj->i", information, errors), P


def expected_norm(covariance: np.ndarray, n_samples: int = 20000, seed: int = 0) -> float:
    """E ||x|| for x ~ N(0, covariance) (k, k), by Monte Carlo with a fixed seed (deterministic)."""
    root = np.linalg.cholesky(np.asarray(covariance, dtype=np.float64))
    samples = np.random.default_rng(seed).standard_normal((n_samples, len(root))) @ root.T
    return float(np.linalg.norm(samples, axis=1).mean())


def scene_bound(T_world_object: np.ndarray, T_world_sensors: np.ndarray, T_world_sensors_reported: np.ndarray,
                sigma_m: float, sigma_rad: float) -> tuple[float, float]:
    """One scene -> (expected, realised) positional error (m) of the oracle (module docstring): the expected
    norm of its position error under the sigmas, and the norm of its error for the sensor errors drawn."""
    A = poses_to_object_jacobians(T_world_object, T_world_sensors)
    C = sensor_covariances(A, sigma_m, sigma_rad)
    errors = implied_object_errors(T_world_object, T_world_sensors, T_world_sensors_reported)
    fused, P = fuse_object_errors(errors, C)
    return expected_norm(P[:3, :3]), float(np.linalg.norm(fused[:3]))
