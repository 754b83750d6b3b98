"""scripts/surface_penetration.py: the surface's penetration into a sensor's box, against depths worked by hand."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree
from script_loader import load_script

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.core.sensor import BOX_CENTER, BOX_HALF_EXTENTS

surface_penetration = load_script("surface_penetration")


def surface_of(points: np.ndarray) -> SimpleNamespace:
    return SimpleNamespace(points=points, tree=cKDTree(points))


@pytest.mark.slow
def test_the_deepest_surface_sample_inside_each_box_is_its_penetration():
    T_sensor = make_pose(rotvec_to_rotmat(np.array([0.0, 0.0, 0.4])), np.array([0.1, -0.2, 0.3]))
    centre = T_sensor[:3, :3] @ BOX_CENTER + T_sensor[:3, 3]  # the box's centre, world
    x_axis = T_sensor[:3, 0]
    # in the object frame (the object at the identity): 2 mm inside the box's +x face, at its centre, and outside
    inside = centre + (BOX_HALF_EXTENTS[0] - 0.002) * x_axis
    points = np.stack([inside, centre + 0.5 * x_axis, centre + (BOX_HALF_EXTENTS[0] + 0.001) * x_axis])
    depths = surface_penetration.surface_to_box_depths(surface_of(points), np.eye(4)[None], T_sensor[None])
    np.testing.assert_allclose(depths, [[0.002]], atol=1e-12)
    # the object moved 3 mm along the box's -x: the sample 5 mm deep; a second sensor far away: 0
    moved = make_pose(np.eye(3), -0.003 * x_axis)
    far = make_pose(np.eye(3), np.array([5.0, 5.0, 5.0]))
    depths = surface_penetration.surface_to_box_depths(surface_of(points), np.stack([np.eye(4), moved]),
                                                       np.stack([T_sensor, far]))
    np.testing.assert_allclose(depths, [[0.002, 0.0], [0.005, 0.0]], atol=1e-12)
