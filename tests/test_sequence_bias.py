"""scripts/sequence_bias.py: its geometry against the kinematic bound's definitions and naive references."""

import numpy as np
from script_loader import load_script

from tactile6d.core.geometry import invert_pose, make_pose, random_rotations, rotvec_to_rotmat
from tactile6d.evaluation.kinematic_bound import seen_through_true_errors
from tactile6d.perception.contacts import Contacts

bias = load_script("sequence_bias")


def random_poses(rng, n):
    return make_pose(random_rotations(n, rng), rng.uniform(-0.1, 0.1, (n, 3)))


def small_motions(rng, n, sigma_m=0.0015, sigma_rad=np.radians(1.5)):
    return make_pose(rotvec_to_rotmat(rng.normal(0, sigma_rad, (n, 3))), rng.normal(0, sigma_m, (n, 3)))


def test_the_corrections_seen_through_the_true_errors_are_those_errors():
    """An object seen through corrections equal to each sensor's true error (the oracle of kinematic_bound) implies
    sensor corrections that take each reported pose to the true one."""
    rng = np.random.default_rng(0)
    T_true, pose = random_poses(rng, 3), random_poses(rng, 1)[0]
    error = small_motions(rng, 3)
    T_reported = T_true @ error  # sim.perturb's convention
    seen = seen_through_true_errors(pose, T_reported, T_true)
    corrections = bias.sensor_corrections(T_reported, pose, seen)
    np.testing.assert_allclose(T_reported @ corrections, T_true, atol=1e-12)
    np.testing.assert_allclose(corrections, invert_pose(error), atol=1e-12)


def test_contacts_read_through_other_sensor_poses_match_a_naive_loop():
    rng = np.random.default_rng(1)
    T_from, T_to = random_poses(rng, 3), random_poses(rng, 3)
    local_points, local_normals = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    world_points = np.stack([T_from[i, :3, :3] @ local_points[i] + T_from[i, :3, 3] for i in range(3)])
    world_normals = np.stack([T_from[i, :3, :3] @ local_normals[i] for i in range(3)])
    masks = np.zeros((3, 4, 4), bool)
    c = Contacts(world_points, world_normals, np.array([True, False, True]), masks, np.zeros((3, 4, 4), np.float32))
    moved = bias.contacts_through(c, T_from, T_to)
    for i in range(3):
        np.testing.assert_allclose(moved.points[i], T_to[i, :3, :3] @ local_points[i] + T_to[i, :3, 3], atol=1e-12)
        np.testing.assert_allclose(moved.normals[i], T_to[i, :3, :3] @ local_normals[i], atol=1e-12)
    np.testing.assert_array_equal(moved.from_patch, c.from_patch)
    assert moved.masks is c.masks


def test_mean_motion_of_a_motion_and_its_opposite_is_none_and_of_one_motion_that_motion():
    rng = np.random.default_rng(2)
    m = small_motions(rng, 2)
    opposite = make_pose(rotvec_to_rotmat(-np.array([[0.01, -0.02, 0.005], [0.0, 0.01, 0.0]])), -m[:, :3, 3])
    forward = make_pose(rotvec_to_rotmat(np.array([[0.01, -0.02, 0.005], [0.0, 0.01, 0.0]])), m[:, :3, 3])
    np.testing.assert_allclose(bias.mean_motion(np.stack([forward, opposite])), np.repeat(np.eye(4)[None], 2, 0),
                               atol=1e-12)
    np.testing.assert_allclose(bias.mean_motion(np.stack([forward, forward, forward])), forward, atol=1e-12)
