"""tactile6d.evaluation.kinematic_bound: the oracle's errors against their definitions and naive references."""

import numpy as np
import pytest

from tactile6d.core.geometry import invert_pose, make_pose, orthonormal_frame, random_rotations, rotvec_to_rotmat
from tactile6d.evaluation import kinematic_bound as kb
from tactile6d.sim import perturb
from tactile6d.sim.scenes import SceneSet
from script_loader import load_script

SIGMA_M, SIGMA_RAD = 0.0015, np.radians(1.5)


def grasp(rng, n_sensors=3, reach=0.06):
    """An object at a random pose and n sensors around it, each looking at it from ``reach`` metres."""
    T_wo = make_pose(random_rotations(1, rng)[0], rng.uniform(-0.1, 0.1, 3))
    sensors = []
    for _ in range(n_sensors):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        sensors.append(make_pose(orthonormal_frame(-d), T_wo[:3, 3] + reach * d))
    return T_wo, np.stack(sensors)


def frame_errors(rng, n, scale=1.0):
    """(n, 4, 4) sensor-frame errors as sim.perturb draws them: T_reported = T_true @ E."""
    return make_pose(rotvec_to_rotmat(rng.normal(0, scale * SIGMA_RAD, (n, 3))), rng.normal(0, scale * SIGMA_M, (n, 3)))


def test_implied_errors_are_the_object_seen_through_the_reported_poses():
    rng = np.random.default_rng(0)
    T_wo, T_ws = grasp(rng)
    reported = T_ws @ frame_errors(rng, 3)
    errors = kb.implied_object_errors(T_wo, T_ws, reported)
    for i in range(3):  # naive: the object's pose relative to sensor i, carried by its reported pose
        implied = reported[i] @ (invert_pose(T_ws[i]) @ T_wo)
        assert np.allclose(errors[i, :3], implied[:3, 3] - T_wo[:3, 3])
        assert np.allclose(rotvec_to_rotmat(errors[i, 3:]) @ T_wo[:3, :3], implied[:3, :3])
    assert np.allclose(kb.implied_object_errors(T_wo, T_ws, T_ws), 0.0)


def test_the_object_seen_through_the_true_errors_keeps_each_true_relative_pose():
    rng = np.random.default_rng(4)
    T_wo, T_ws = grasp(rng)
    reported = T_ws @ frame_errors(rng, 3)
    seen = kb.seen_through_true_errors(T_wo, reported, T_ws)
    for i in range(3):
        np.testing.assert_allclose(invert_pose(reported[i]) @ seen[i], invert_pose(T_ws[i]) @ T_wo, atol=1e-12)
        # ... which is the object as the sensor's reported pose implies it (implied_object_errors' pose)
        np.testing.assert_allclose(seen[i][:3, 3] - T_wo[:3, 3], kb.implied_object_errors(T_wo, T_ws, reported)[i, :3],
                                   atol=1e-12)
    np.testing.assert_allclose(kb.seen_through_true_errors(T_wo, T_ws, T_ws), np.repeat(T_wo[None], 3, axis=0), atol=1e-12)


def test_jacobians_are_the_first_order_of_the_implied_errors():
    rng = np.random.default_rng(1)
    T_wo, T_ws = grasp(rng)
    A = kb.poses_to_object_jacobians(T_wo, T_ws)
    for i in range(3):
        for k in range(6):  # finite differences, one frame-error component at a time
            step = np.zeros(6)
            step[k] = 1e-6
            E = make_pose(rotvec_to_rotmat(step[3:]), step[:3])
            column = kb.implied_object_errors(T_wo, T_ws[i:i + 1], T_ws[i:i + 1] @ E)[0] / 1e-6
            assert np.allclose(column, A[i, :, k], atol=1e-5)


def test_a_rotation_error_moves_the_object_by_its_lever_arm():
    """A sensor turned by w about its own origin moves an object 6 cm in front of it by about w x 6 cm."""
    T_ws = np.eye(4)[None]
    T_wo = make_pose(np.eye(3), [0.06, 0.0, 0.0])
    E = make_pose(rotvec_to_rotmat(np.array([[0.0, 0.0, 0.01]])), np.zeros((1, 3)))
    error = kb.implied_object_errors(T_wo, T_ws, T_ws @ E)[0]
    assert error[:3] == pytest.approx([0.06 * (np.cos(0.01) - 1), 0.06 * np.sin(0.01), 0.0])


def test_fusion_is_the_weighted_least_squares_solution():
    rng = np.random.default_rng(2)
    T_wo, T_ws = grasp(rng, n_sensors=4)
    C = kb.sensor_covariances(kb.poses_to_object_jacobians(T_wo, T_ws), SIGMA_M, SIGMA_RAD)
    errors = rng.normal(size=(4, 6)) * 1e-3
    fused, P = kb.fuse_object_errors(errors, C)
    # Naive: whiten each reading by its covariance's Cholesky factor, stack, solve by least squares.
    rows, rhs = [], []
    for e, c in zip(errors, C):
        W = np.linalg.inv(np.linalg.cholesky(c))
        rows.append(W)
        rhs.append(W @ e)
    x, *_ = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)
    assert np.allclose(fused, x, rtol=1e-6, atol=1e-12)
    stacked = np.concatenate(rows)
    assert np.allclose(P, np.linalg.inv(stacked.T @ stacked), rtol=1e-6, atol=1e-16)


def test_one_sensor_is_its_own_reading_and_identical_ones_average():
    rng = np.random.default_rng(3)
    T_wo, T_ws = grasp(rng, n_sensors=1)
    C = kb.sensor_covariances(kb.poses_to_object_jacobians(T_wo, T_ws), SIGMA_M, SIGMA_RAD)
    e = rng.normal(size=(1, 6)) * 1e-3
    fused, P = kb.fuse_object_errors(e, C)
    assert np.allclose(fused, e[0]) and np.allclose(P, C[0])
    fused, P = kb.fuse_object_errors(np.stack([e[0], -e[0], 3 * e[0]]), np.repeat(C, 3, axis=0))
    assert np.allclose(fused, e[0]) and np.allclose(P, C[0] / 3)


@pytest.mark.slow
def test_the_expected_bound_matches_the_realised_errors_over_many_draws():
    """The expected norm under the fused covariance against the oracle's realised errors for drawn sensor errors."""
    rng = np.random.default_rng(4)
    T_wo, T_ws = grasp(rng)
    draws = [kb.scene_bound(T_wo, T_ws, T_ws @ frame_errors(rng, 3), SIGMA_M, SIGMA_RAD) for _ in range(3000)]
    expected, realised = np.array(draws).T
    assert np.all(expected == expected[0])  # it depends on the geometry only
    assert realised.mean() == pytest.approx(expected[0], rel=0.05)


def test_the_bound_scales_with_the_error_and_is_the_mean_of_l_readings_without_rotation():
    rng = np.random.default_rng(5)
    T_wo, T_ws = grasp(rng)
    bound = kb.scene_bound(T_wo, T_ws, T_ws, SIGMA_M, SIGMA_RAD)[0]
    assert kb.scene_bound(T_wo, T_ws, T_ws, 2 * SIGMA_M, 2 * SIGMA_RAD)[0] == pytest.approx(2 * bound, rel=1e-6)
    assert kb.scene_bound(T_wo, T_ws, T_ws, SIGMA_M, SIGMA_RAD)[1] < 1e-12  # poses as true: no error
    # Translation errors alone: the mean of three isotropic readings, E||N(0, s^2/3 I3)|| = s/sqrt(3) 2 sqrt(2/pi).
    alone = kb.scene_bound(T_wo, T_ws, T_ws, SIGMA_M, 1e-9)[0]
    assert alone == pytest.approx(SIGMA_M / np.sqrt(3) * 2 * np.sqrt(2 / np.pi), rel=0.01)
    assert bound > alone


def posed_set(n: int = 4, sensors: int = 3) -> SceneSet:
    rng = np.random.default_rng(5)
    T = make_pose(rotvec_to_rotmat(rng.normal(0, 1, (n, sensors, 3))), rng.normal(0, 0.05, (n, sensors, 3)))
    return SceneSet(np.array([f"s{i}" for i in range(n)]), np.array(["box"] * n), np.broadcast_to(np.eye(4), (n, 4, 4)),
                    T, np.zeros((n, sensors, 2, 2, 3), np.uint8), np.zeros((n, sensors, 3)), np.zeros((n, sensors, 3)),
                    np.zeros((n, sensors), np.int64))


def test_the_true_sensor_poses_are_recovered_from_a_kinematic_set():
    clean = posed_set()
    off = perturb.perturb_sensor_poses(clean, 0.002, np.radians(2.0), np.random.default_rng(3))
    stored = off.as_datasets()
    for s in range(len(clean)):
        assert not np.allclose(stored["T_world_sensors"][s], clean.T_world_sensors[s], atol=1e-4)
        np.testing.assert_allclose(kb.true_sensor_poses(stored, s), clean.T_world_sensors[s], atol=1e-12)


def test_a_set_without_sensor_pose_errors_has_no_true_poses_to_offer():
    assert kb.true_sensor_poses(posed_set().as_datasets(), 0) is None


def test_the_script_bounds_every_scene_of_a_perturbed_set_and_refuses_a_clean_one():
    script = load_script("kinematic_bound")
    clean = posed_set()
    off = perturb.perturb_sensor_poses(clean, SIGMA_M, SIGMA_RAD, np.random.default_rng(8)).as_datasets()
    expected, realised = script.set_bounds(off, SIGMA_M, SIGMA_RAD)
    assert len(expected) == len(realised) == len(clean)
    assert all(e > 0 for e in expected) and all(r > 0 for r in realised)
    with pytest.raises(SystemExit):
        script.set_bounds(clean.as_datasets(), SIGMA_M, SIGMA_RAD)
