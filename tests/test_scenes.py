import numpy as np
import pytest
import trimesh

from tactile6d.core.geometry import make_pose, random_rotations
from tactile6d.core.sensor import BOX_CENTER, BOX_HALF_EXTENTS, bodies_overlap, sensor_poses_touching
from tactile6d.sim import contact_types, scenes, surface_sampling


def box_points(T, n, rng):
    """Random points inside a sensor's body box, in the world."""
    local = BOX_CENTER + rng.uniform(-1, 1, (n, 3)) * BOX_HALF_EXTENTS
    return local @ T[:3, :3].T + T[:3, 3]


def naive_overlap(T_a, T_b, rng, n=20000):
    """Reference by sampling: some point of box a lies inside box b (misses only grazing overlaps)."""
    p = box_points(T_a, n, rng)
    local = (p - T_b[:3, 3]) @ T_b[:3, :3]
    return bool(np.any(np.all(np.abs(local - BOX_CENTER) < BOX_HALF_EXTENTS, axis=1)))


def test_bodies_overlap_matches_sampling():
    rng = np.random.default_rng(0)
    agree = 0
    for _ in range(60):
        T_a = make_pose(random_rotations(1, rng)[0], rng.uniform(-0.04, 0.04, 3))
        T_b = make_pose(random_rotations(1, rng)[0], rng.uniform(-0.04, 0.04, 3))
        exact = bodies_overlap(T_a, T_b)
        sampled = naive_overlap(T_a, T_b, rng) or naive_overlap(T_b, T_a, rng)
        if sampled:
            assert exact  # sampling never invents an overlap
        agree += exact == sampled
    assert agree >= 57  # sampling may miss a few grazing overlaps


@pytest.fixture(scope="module")
def box():
    mesh = trimesh.creation.box(extents=(0.10, 0.08, 0.06))
    return mesh, surface_sampling.sample_surface(mesh)


def test_body_penetration(box):
    _mesh, surface = box
    T = sensor_poses_touching([0.0, 0.0, 0.03], [0.0, 0.0, 1.0], 0.0, 0.0018)
    assert not scenes.body_penetrates(surface, T)
    T_deep = sensor_poses_touching([0.0, 0.0, 0.03], [0.0, 0.0, 1.0], 0.0, 0.004)  # body 0.4 mm into the face
    assert scenes.body_penetrates(surface, T_deep)
    # at an edge, a sensor facing the top face hangs over: fine; one facing diagonally inward is not
    T_edge = sensor_poses_touching([0.05, 0.0, 0.03], [0.0, 0.0, 1.0], 0.0, 0.0018)
    assert not scenes.body_penetrates(surface, T_edge)


def test_body_wholly_inside_the_object_penetrates():
    # A hollow-free big box with the sensor's whole body inside it: no surface sample lies in the body
    # box, yet the sensor is inside the solid (a candidate normal that faces inward places it there).
    mesh = trimesh.creation.box(extents=(0.30, 0.30, 0.30))
    surface = surface_sampling.sample_surface(mesh, spacing=0.004)
    T_inside = make_pose(np.eye(3), -BOX_CENTER)  # body box centred on the object's centre
    local = (surface.points - T_inside[:3, 3]) @ T_inside[:3, :3]
    assert not np.any(np.all(np.abs(local - BOX_CENTER) < BOX_HALF_EXTENTS, axis=1))  # the old test's blind spot
    assert scenes.body_penetrates(surface, T_inside)
    T_outside = make_pose(np.eye(3), [0.3, 0.0, 0.0])
    assert not scenes.body_penetrates(surface, T_outside)


def test_validation_scene_mixes_types_without_collisions(box):
    mesh, surface = box
    rng = np.random.default_rng(1)
    spec = scenes.ValidationSpec(candidates_per_object=400)
    db = np.array([[1.0, 1.0, 1.0]])
    cand, cand_n, cand_t = scenes.validation_candidates(mesh, surface, db, spec, rng)
    assert set(np.unique(cand_t)) >= {contact_types.FLAT, contact_types.EDGE}
    seen = set()
    for _ in range(8):
        T, idx, depth = scenes.draw_validation_scene(mesh, surface, cand, cand_n, cand_t, spec, rng)
        assert T.shape == (3, 4, 4) and len(set(idx.tolist())) == 3
        assert np.all((depth >= 0.0015) & (depth <= 0.002))
        for i in range(3):
            assert not scenes.body_penetrates(surface, T[i])
            for j in range(i):
                assert not bodies_overlap(T[i], T[j])
        seen |= set(cand_t[idx].tolist())
    assert len(seen) >= 2


def test_generate_validation_ground_truth_is_consistent(box):
    mesh, surface = box
    spec = scenes.ValidationSpec(scenes_per_object=2, candidates_per_object=300)
    calls = []

    def render(obj, T_wo, T_ws, seed):
        calls.append(seed)
        return np.zeros((len(T_ws), 320, 240, 3), np.uint8)

    out = scenes.generate_validation(["b"], {"b": mesh}, {"b": surface}, {"b": np.zeros((1, 3)) + 1}, render, spec, seed=3)
    assert len(out) == 2 and out.images.shape == (2, 3, 320, 240, 3) and len(calls) == 2
    # the recorded contact point lies on the object at its pose, the sensor's landmark just outside it
    for s in range(2):
        local = (out.contact_points[s] - out.T_world_object[s, :3, 3]) @ out.T_world_object[s, :3, :3]
        _, dist, _ = trimesh.proximity.closest_point(mesh, local)
        assert dist.max() < 1e-6
        landmark = out.T_world_sensors[s, :, :3, 3] + out.T_world_sensors[s, :, :3, :3] @ np.array([0.02, 0, 0.015])
        gap = np.sum((landmark - out.contact_points[s]) * out.contact_normals[s], axis=1)
        assert np.all((gap >= 0) & (gap <= 0.0005 + 1e-9))
    again = scenes.generate_validation(["b"], {"b": mesh}, {"b": surface}, {"b": np.zeros((1, 3)) + 1}, render, spec, seed=3)
    np.testing.assert_array_equal(again.T_world_sensors, out.T_world_sensors)


def test_a_scene_whose_sensors_cannot_all_be_placed_is_drawn_again(box, monkeypatch):
    """When the first sensors leave no room for the rest (PlacementError), the scene is drawn again
    instead of stopping the whole set."""
    mesh, surface = box
    spec = scenes.ValidationSpec(scenes_per_object=2, candidates_per_object=300)
    draw, calls = scenes.draw_validation_scene, []

    def first_draw_fails(*args):
        calls.append(1)
        if len(calls) == 1:
            raise scenes.PlacementError("no room")
        return draw(*args)

    monkeypatch.setattr(scenes, "draw_validation_scene", first_draw_fails)
    out = scenes.generate_validation(["b"], {"b": mesh}, {"b": surface}, {"b": np.zeros((1, 3)) + 1},
                                     lambda obj, T_wo, T_ws, seed: np.zeros((len(T_ws), 320, 240, 3), np.uint8),
                                     spec, seed=3)
    assert len(out) == 2 and len(calls) == 3


def test_off_axis_pose_without_tilt_or_offset_is_the_apex_contact():
    rng = np.random.default_rng(3)
    p, n = rng.normal(size=3) * 0.05, rng.normal(size=3)
    n /= np.linalg.norm(n)
    for roll, depth in ((0.0, 0.0018), (1.2, 0.001)):
        expected = sensor_poses_touching(p, n, roll, depth)
        got = scenes.sensor_pose_touching_off_axis(p, n, roll, depth, 0.7, 0.0, np.zeros(2))
        np.testing.assert_allclose(got, expected, atol=1e-12)


def test_off_axis_pose_tilts_by_the_angle_and_presses_the_chosen_gel_point():
    rng = np.random.default_rng(4)
    p, n = rng.normal(size=3) * 0.05, rng.normal(size=3)
    n /= np.linalg.norm(n)
    tilt, depth, offset = np.radians(15.0), 0.0013, np.array([0.003, -0.002])
    T = scenes.sensor_pose_touching_off_axis(p, n, 0.4, depth, 2.0, tilt, offset)
    assert np.degrees(np.arccos(T[:3, 0] @ -n)) == pytest.approx(15.0)
    g = scenes.gel_point(*offset)
    np.testing.assert_allclose(T[:3, :3] @ (g - [depth, 0, 0]) + T[:3, 3], p, atol=1e-12)
    # the gel point lies on the gel, off its centre toward the asked offset, and behind the apex
    assert 0 < g[1] <= 0.003 and -0.002 <= g[2] - 0.015 < 0 and g[0] < 0.022
