"""scripts/pose_floor.py: its figures' units (the true sensor poses it estimates through: tests/test_kinematic_bound.py)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from tactile6d.core.geometry import make_pose

spec = importlib.util.spec_from_file_location("pose_floor", Path(__file__).parents[1] / "scripts" / "pose_floor.py")
pose_floor = importlib.util.module_from_spec(spec)
spec.loader.exec_module(pose_floor)


def test_positions_are_compared_in_centimetres():
    a, b = np.eye(4), make_pose(np.eye(3), [0.03, 0.04, 0.0])
    assert pose_floor.position_cm(a, b) == pytest.approx(5.0)
