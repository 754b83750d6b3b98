"""scripts/pose_floor.py: its figures' units (the true sensor poses it estimates through: tests/test_kinematic_bound.py)."""


import numpy as np
import pytest

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat, transform_points
from script_loader import load_script

pose_floor = load_script("pose_floor")


def test_positions_are_compared_in_centimetres():
    a, b = np.eye(4), make_pose(np.eye(3), [0.03, 0.04, 0.0])
    assert pose_floor.position_cm(a, b) == pytest.approx(5.0)


def _sensors_and_truth():
    rng = np.random.default_rng(3)
    truth = make_pose(rotvec_to_rotmat(np.array([0.3, -0.2, 0.5])), [0.1, 0.0, 0.2])
    sensors = np.stack([make_pose(rotvec_to_rotmat(rng.normal(0, 1, 3)), rng.normal(0, 0.05, 3)) for _ in range(3)])
    contacts_in_sensors = rng.normal(0.0, 0.01, (3, 3)) + [0.022, 0.0, 0.015]
    return truth, sensors, contacts_in_sensors


def test_the_oracle_fit_through_exact_sensor_poses_is_the_truth():
    truth, sensors, local = _sensors_and_truth()
    points = np.stack([transform_points(sensors[i], local[i][None])[0] for i in range(3)])
    fit = pose_floor.oracle_fit(sensors, sensors, truth, points)
    assert np.allclose(fit, truth, atol=1e-9)


def test_the_oracle_fit_carries_a_common_sensor_error_onto_the_object():
    # Every sensor reported 3 mm off along the world x axis: the contacts as read move with them, and the fit
    # puts the object where those contacts say, 3 mm off the same way.
    truth, true_sensors, local = _sensors_and_truth()
    shift = make_pose(np.eye(3), [0.003, 0.0, 0.0])
    reported = shift[None] @ true_sensors
    points = np.stack([transform_points(reported[i], local[i][None])[0] for i in range(3)])
    fit = pose_floor.oracle_fit(reported, true_sensors, truth, points)
    assert np.allclose(fit, shift @ truth, atol=1e-9)


def test_starts_begin_with_the_pose_itself_and_spread_as_asked():
    T = make_pose(rotvec_to_rotmat(np.array([0.1, 0.2, 0.3])), [0.1, 0.0, 0.2])
    starts = pose_floor.starts_around(T, 400, 0.002, np.radians(2.0), np.random.default_rng(0))
    assert starts.shape == (401, 4, 4) and np.array_equal(starts[0], T)
    local = np.linalg.inv(T)[None] @ starts[1:]
    assert np.std(local[:, :3, 3]) == pytest.approx(0.002, rel=0.1)
    angles = np.degrees(np.arccos(np.clip((np.trace(local[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert np.median(angles) == pytest.approx(2.0 * 1.538, rel=0.15)  # median of a 3-D Gaussian's norm: 1.538 sigma


def test_weighted_pose_mean_against_a_naive_one():
    """Poses spread symmetrically about T with equal scores average to T; a tiny tau keeps the best; with two
    poses of equal weight the translation is their midpoint and the rotation halfway (one axis)."""
    T = make_pose(rotvec_to_rotmat(np.array([0.2, -0.1, 0.4])), [0.05, 0.01, 0.3])
    steps = [make_pose(rotvec_to_rotmat(np.array(v) * 0.02), np.array(v) * 0.001)
             for v in ([1, 0, 0], [0, 1, 0], [0, 0, 1])]
    poses = np.stack([T @ step for step in steps] + [T @ np.linalg.inv(step) for step in steps])
    mean = pose_floor.weighted_pose_mean(poses, np.zeros(6), tau=1.0)
    assert np.allclose(mean[:3, 3], T[:3, 3], atol=1e-12)
    assert np.allclose(mean[:3, :3], T[:3, :3], atol=1e-12)  # T times a symmetric positive matrix: its polar factor is T
    scores = np.array([3.0, 1.0, 2.0, 5.0, 4.0, 6.0])
    assert np.allclose(pose_floor.weighted_pose_mean(poses, scores, tau=1e-3), poses[1], atol=1e-12)

    a, b = make_pose(np.eye(3), [0.0, 0.0, 0.0]), make_pose(rotvec_to_rotmat(np.array([0.0, 0.0, 0.6])), [0.02, 0.0, 0.0])
    mid = pose_floor.weighted_pose_mean(np.stack([a, b]), np.array([0.5, 0.5]), tau=1.0)
    assert np.allclose(mid[:3, 3], [0.01, 0.0, 0.0])
    assert np.allclose(mid[:3, :3], rotvec_to_rotmat(np.array([0.0, 0.0, 0.3])), atol=1e-12)
