"""scripts/track_ambiguity.py: how well a pose's presses match the recorded ones, with the project's renderer."""


import numpy as np
import pytest
import trimesh

from tactile6d.core import geometry as g
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.sim.render import DigitRenderer, mesh_arrays
from script_loader import load_script

track_ambiguity = load_script("track_ambiguity")

pytestmark = pytest.mark.slow  # it renders


@pytest.fixture(scope="module")
def pressed():
    """A 3 cm sphere at the origin pressed 1.5 mm by two sensors from +x and +y, and their recorded depths."""
    renderer = DigitRenderer.from_default_config(np.full((320, 240, 3), (100, 120, 140), np.uint8), workers=1)
    arrays = mesh_arrays(trimesh.creation.icosphere(subdivisions=4, radius=0.03))
    normals = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    T_sensors = sensor_poses_touching(0.03 * normals, normals, 0.0, 0.0015)
    recorded = [renderer.contact(arrays, g.invert_pose(T) @ np.eye(4))[1] for T in T_sensors]
    return renderer, arrays, T_sensors, recorded


def test_the_recorded_pose_matches_itself(pressed):
    renderer, arrays, T_sensors, recorded = pressed
    assert all(d.max() > 0.001 for d in recorded)
    iou, depth_mm = track_ambiguity.press_agreement(renderer, arrays, np.eye(4), T_sensors, recorded)
    assert iou == 1.0 and depth_mm == 0.0


def test_a_pose_that_presses_otherwise_is_told_apart(pressed):
    """Moved 0.5 mm away from the +x sensor: that press is shallower and smaller, the +y one slides along."""
    renderer, arrays, T_sensors, recorded = pressed
    moved = g.make_pose(np.eye(3), [-0.0005, 0.0, 0.0])
    iou, depth_mm = track_ambiguity.press_agreement(renderer, arrays, moved, T_sensors, recorded)
    assert 0.3 < iou < 0.95 and 0.1 < depth_mm < 1.0
    far = g.make_pose(np.eye(3), [0.0, 0.0, 0.1])  # out of reach: no press where the recorded ones are
    iou, depth_mm = track_ambiguity.press_agreement(renderer, arrays, far, T_sensors, recorded)
    assert iou == 0.0 and depth_mm > 0.1
