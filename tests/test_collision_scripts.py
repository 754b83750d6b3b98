"""scripts/collision_excess.py and scripts/surface_penetration.py: their depths against naive references, and
the rank module left as it was."""

import numpy as np
import trimesh
from scipy.spatial import cKDTree

import tactile6d.estimation.rank as rank_module
from script_loader import load_script
from tactile6d.core.geometry import make_pose, random_rotations
from tactile6d.core.sensor import BOX_CENTER, BOX_HALF_EXTENTS
from tactile6d.estimation.collision import box_point_depth, sensor_box_poses, vertices_to_pieces
from tactile6d.sim.surface_sampling import sample_surface

collision_excess = load_script("collision_excess")
surface_penetration = load_script("surface_penetration")


def test_points_inside_two_boxes_are_as_deep_as_the_deeper_box_says():
    """Two overlapping axis-aligned boxes as pieces: a point's depth is the larger of its distances to each box's
    nearest face (the naive reference, ``box_point_depth``), 0 outside both."""
    a, b = trimesh.creation.box([0.04, 0.02, 0.02]), trimesh.creation.box([0.02, 0.04, 0.02])
    b.apply_translation([0.01, 0.0, 0.0])
    pieces = vertices_to_pieces([a.vertices, b.vertices])
    points = np.random.default_rng(0).uniform(-0.03, 0.03, (2000, 3))
    expected = np.maximum(box_point_depth(points, np.array([0.02, 0.01, 0.01])),
                          box_point_depth(points - [0.01, 0.0, 0.0], np.array([0.01, 0.02, 0.01])))
    np.testing.assert_allclose(collision_excess.points_to_piece_depth(points, pieces), expected, atol=1e-12)


class _Samples:
    def __init__(self, points):
        self.points, self.tree = points, cKDTree(points)


def test_surface_depths_match_every_sample_checked_and_a_pressed_face():
    """A cube's surface pressed into one sensor's box: the tree-limited search gives the depth that checking every
    sample in the box frame gives, and a face pressed d past the box's front is d deep (to the sampling)."""
    cube = trimesh.creation.box([0.05, 0.05, 0.05])
    surface = sample_surface(cube)
    T_sensor = np.eye(4)[None]
    box = sensor_box_poses(T_sensor)[0]
    front = box[0, 3] + BOX_HALF_EXTENTS[0]  # the box's face towards +x, where the gel is
    rng = np.random.default_rng(1)
    poses = [make_pose(np.eye(3), [front + 0.025 - depth, BOX_CENTER[1], BOX_CENTER[2]]) for depth in (0.0, 5e-4, 2e-3)]
    poses += [make_pose(R, [front + 0.02, 0.0, 0.017]) for R in random_rotations(3, rng)]
    poses = np.stack(poses)
    got = surface_penetration.surface_to_box_depths(_Samples(surface.points), poses, T_sensor)
    for p, T in enumerate(poses):
        local = (surface.points @ T[:3, :3].T + T[:3, 3]) - box[:3, 3]  # every sample, in the box's frame
        np.testing.assert_allclose(got[p, 0], box_point_depth(local, BOX_HALF_EXTENTS).max(), atol=1e-12)
    np.testing.assert_allclose(got[:3, 0], [0.0, 5e-4, 2e-3], atol=1e-9)


def test_the_swap_puts_the_rank_function_back():
    before = rank_module.seen_penetrations
    with surface_penetration.surface_penetration({}):
        assert rank_module.seen_penetrations is not before
    assert rank_module.seen_penetrations is before
