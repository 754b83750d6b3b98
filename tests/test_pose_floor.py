"""scripts/pose_floor.py: the true sensor poses it estimates through are those a kinematic set was made from."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.sim import perturb
from tactile6d.sim.scenes import SceneSet

spec = importlib.util.spec_from_file_location("pose_floor", Path(__file__).parents[1] / "scripts" / "pose_floor.py")
pose_floor = importlib.util.module_from_spec(spec)
spec.loader.exec_module(pose_floor)


def scene_set(n: int = 4, sensors: int = 3) -> SceneSet:
    rng = np.random.default_rng(5)
    T = make_pose(rotvec_to_rotmat(rng.normal(0, 1, (n, sensors, 3))), rng.normal(0, 0.05, (n, sensors, 3)))
    return SceneSet(np.array([f"s{i}" for i in range(n)]), np.array(["box"] * n), np.broadcast_to(np.eye(4), (n, 4, 4)),
                    T, np.zeros((n, sensors, 2, 2, 3), np.uint8), np.zeros((n, sensors, 3)), np.zeros((n, sensors, 3)),
                    np.zeros((n, sensors), np.int64))


def test_the_true_sensor_poses_are_recovered_from_a_kinematic_set():
    clean = scene_set()
    off = perturb.perturb_sensor_poses(clean, 0.002, np.radians(2.0), np.random.default_rng(3))
    stored = off.as_datasets()
    for s in range(len(clean)):
        assert not np.allclose(stored["T_world_sensors"][s], clean.T_world_sensors[s], atol=1e-4)
        np.testing.assert_allclose(pose_floor.true_sensor_poses(stored, s), clean.T_world_sensors[s], atol=1e-12)


def test_a_set_without_sensor_pose_errors_has_no_true_poses_to_offer():
    assert pose_floor.true_sensor_poses(scene_set().as_datasets(), 0) is None


def test_positions_are_compared_in_centimetres():
    a, b = np.eye(4), make_pose(np.eye(3), [0.03, 0.04, 0.0])
    assert pose_floor.position_cm(a, b) == pytest.approx(5.0)
