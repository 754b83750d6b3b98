"""scripts/pose_floor.py: its figures' units (the true sensor poses it estimates through: tests/test_kinematic_bound.py)."""


import numpy as np
import pytest

from tactile6d.core.geometry import make_pose
from script_loader import load_script

pose_floor = load_script("pose_floor")


def test_positions_are_compared_in_centimetres():
    a, b = np.eye(4), make_pose(np.eye(3), [0.03, 0.04, 0.0])
    assert pose_floor.position_cm(a, b) == pytest.approx(5.0)
