import gc
import sys

import numpy as np
import pytest
import trimesh

from tactile6d.core import sensor
from tactile6d.core.geometry import invert_pose, make_pose, rotvec_to_rotmat
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.estimation import optimize, render_and_compare
from tactile6d.sim import gel_press
from tactile6d.sim.meshes import make_primitive
from tactile6d.sim.render import CAMERA_POSITION, DigitRenderer, gel_surface, mesh_arrays, pixel_rays

T_GT = make_pose(rotvec_to_rotmat([0.2, -0.1, 0.3]), [0.1, 0.0, 0.2])


@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box(extents=(0.12, 0.08, 0.05))


def box_sensors(T_world_object, depth=0.0018):
    """Three sensors pressing the box's top face, an end face (near a corner) and a side face."""
    p = np.array([[0.0, 0.0, 0.025], [0.06, 0.03, 0.015], [0.01, -0.04, 0.0]])
    n = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    return T_world_object @ sensor_poses_touching(p, n, [0.0, 0.4, -1.0], depth)


def perturbed(T, rotvec, shift):
    return T @ make_pose(rotvec_to_rotmat(rotvec), shift)


def assert_renderers_depths(depth, expected):
    """The renderer's depths, but for rays that graze a triangle's edge within single-precision rounding
    (docs/speed.md, What keeps the default path fast): at most 1 % of the pressed rays, less than 2 mm apart."""
    pressed = np.count_nonzero((depth > 0) | (expected > 0))
    differ = depth != expected
    assert np.count_nonzero(differ) <= max(1, 0.01 * pressed)
    assert np.abs(depth - expected).max() < 0.002


@pytest.mark.parametrize("step", [4, 8])
def test_depth_is_the_renderers_on_the_same_grid(box, step):
    rounded = make_primitive("prim_rounded_box")
    renderer = DigitRenderer.from_default_config(np.zeros((320, 240, 3), np.uint8), render_step=step, strict=False, noise_std=0.0)
    rng = np.random.default_rng(0)
    for mesh in (box, rounded):
        sensors = box_sensors(T_GT) if mesh is box else T_GT @ sensor_poses_touching(
            np.array([[0.0, 0.0, 0.025], [0.032, 0.022, 0.017] + 0.008 / np.sqrt(3), [0.0, -0.03, 0.0]]),
            np.array([[0, 0, 1.0], [1.0, 1.0, 1.0], [0, -1.0, 0]]), 0.3, 0.0018)
        # small and large errors: touching, penetrating deep into the body (strict=False), far away
        poses = np.stack([T_GT] + [perturbed(T_GT, rng.normal(0, 0.05, 3), rng.normal(0, 0.004, 3))
                                   for _ in range(4)]
                         + [perturbed(T_GT, [0, 0, 0], [0, 0, 0.006]), perturbed(T_GT, [0, 0, 0], [0, 0, -0.01])])
        depth = gel_press.poses_to_gel_depths(mesh, poses, sensors, step=step)
        assert depth.shape == (len(poses), 3, 320 // step, 240 // step) and depth.dtype == np.float32
        arrays = mesh_arrays(mesh)
        for p, T in enumerate(poses):
            for i, T_sensor in enumerate(sensors):
                _, expected = renderer.contact(arrays, invert_pose(T_sensor) @ T)
                assert_renderers_depths(depth[p, i], expected)
        assert (depth[0] > 0).any(axis=(1, 2)).all()  # every sensor touches at the true pose
        assert depth[5, 0].max() > renderer.max_press  # the top sensor pressed into the body


def test_first_hits_facing_away_are_left_to_the_renderer(monkeypatch):
    """A 1 mm plate without its top face, pressed 1.8 mm from above and from below: the top sensor's rays
    enter through the hole and first meet the bottom's inside, a triangle facing away from the camera,
    which the renderer leaves out. Those pairs go to the renderer; the rest are cast in one batch; all
    equal the renderer's depths."""
    full = trimesh.creation.box(extents=(0.12, 0.08, 0.001))
    open_plate = trimesh.Trimesh(full.vertices, full.faces[full.face_normals[:, 2] < 0.9], process=False)
    sensors = T_GT @ sensor_poses_touching(np.array([[0.0, 0.0, 0.0005], [0.02, 0.0, -0.0005]]),
                                           np.array([[0, 0, 1.0], [0, 0, -1.0]]), [0.0, 0.3], 0.0018)
    poses = np.stack([T_GT, perturbed(T_GT, [0.02, 0.0, -0.01], [0.001, 0.0, 0.0002])])
    renderer = gel_press.depth_renderer(8)
    calls = []
    original = renderer.contact_depth
    monkeypatch.setattr(renderer, "contact_depth", lambda *a: calls.append(1) or original(*a))
    depth = gel_press.poses_to_gel_depths(open_plate, poses, sensors, step=8)
    assert len(calls) == 2  # the top sensor of each pose, and only those
    arrays = mesh_arrays(open_plate)
    for p, T in enumerate(poses):
        for i, T_sensor in enumerate(sensors):
            assert_renderers_depths(depth[p, i], original(arrays, invert_pose(T_sensor) @ T))
    assert (depth[:, 1] > 0).any(axis=(1, 2)).all()  # the bottom face, pressed from below


def test_batches_of_any_size_give_the_same_depths(box, monkeypatch):
    sensors = box_sensors(T_GT)
    rng = np.random.default_rng(3)
    poses = np.stack([perturbed(T_GT, rng.normal(0, 0.03, 3), rng.normal(0, 0.002, 3)) for _ in range(5)])
    whole = gel_press.poses_to_gel_depths(box, poses, sensors, step=8)
    monkeypatch.setattr(gel_press, "_RAYS_PER_CAST", 2 * 40 * 30)  # two pairs per Embree call
    np.testing.assert_array_equal(gel_press.poses_to_gel_depths(box, poses, sensors, step=8), whole)
    one_by_one = [gel_press.poses_to_gel_depths(box, T, sensors, step=8)[0] for T in poses]
    np.testing.assert_array_equal(np.stack(one_by_one), whole)


def test_a_mesh_scene_is_built_once_and_dropped_with_the_mesh():
    mesh = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    scene = gel_press._object_scene(mesh)
    assert gel_press._object_scene(mesh) is scene
    other = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    assert gel_press._object_scene(other) is not scene
    key = id(mesh)
    del mesh, scene
    gc.collect()
    assert key not in gel_press._SCENES


def test_a_scene_is_dropped_quietly_after_the_module_globals_are_gone(monkeypatch):
    """At interpreter exit a module's globals may be set to None before the last meshes die; the scene's
    callback must not need them (it printed "Exception ignored ... 'NoneType' object has no attribute 'pop'")."""
    mesh = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    scenes, key = gel_press._SCENES, id(mesh)
    gel_press._object_scene(mesh)
    monkeypatch.setattr(gel_press, "_SCENES", None)  # as module teardown leaves it
    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    del mesh
    gc.collect()
    assert not unraisable, [str(u.exc_value) for u in unraisable]
    assert key not in scenes


def test_depth_on_a_flat_face_is_the_gel_minus_the_plane():
    """Naive reference: a sensor square on a big flat face, the face plane at x = apex - press."""
    mesh = trimesh.creation.box(extents=(0.2, 0.2, 0.05))
    press = 0.0015
    T_sensor = sensor_poses_touching(np.array([0.0, 0.0, 0.025]), np.array([0, 0, 1.0]), 0.0, press)
    depth = gel_press.poses_to_gel_depths(mesh, np.eye(4), T_sensor[None], step=8)[0, 0]
    gel_points, _ = gel_surface(pixel_rays(sensor.IMAGE_WIDTH, sensor.IMAGE_HEIGHT, 8))
    gel_t = gel_points[..., 0] - CAMERA_POSITION[0]  # camera-axis distance of the gel along each ray
    plane_x = sensor.GEL_CENTER[0] - press
    # the ray (1, u, v) from the camera meets the plane at camera-axis distance plane_x
    expected = np.maximum(gel_t - plane_x, 0.0)
    np.testing.assert_allclose(depth, expected, atol=1e-6)
    assert depth.max() == pytest.approx(press, abs=1e-5)  # the rays nearest the apex
    assert 0 < (depth > 0).mean() < 1  # a pressed disc, not the whole gel


def test_mask_iou_by_hand():
    a = np.zeros((2, 4, 4), dtype=bool)
    b = np.zeros((2, 4, 4), dtype=bool)
    a[0, :2, :2] = True  # 4 cells
    b[0, 1:3, :2] = True  # 4 cells, 2 shared: IoU 2 / 6
    a[1, 0, 0] = True  # no overlap with an empty mask: 0
    np.testing.assert_allclose(gel_press.mask_iou(a, b), [2 / 6, 0.0])
    assert gel_press.mask_iou(np.zeros((3, 3), bool), np.zeros((3, 3), bool)) == 1.0
    assert gel_press.mask_iou(a[0], a[0]) == 1.0


def test_masks_to_image_consistent_needs_every_sensor():
    true = np.zeros((2, 4, 4), dtype=bool)
    true[:, :2, :2] = True
    est = true.copy()
    est[1, 2, :2] = True  # sensor 1: IoU 4 / 6
    assert gel_press.masks_to_image_consistent(est, true, iou_min=0.5)
    assert not gel_press.masks_to_image_consistent(est, true, iou_min=0.7)
    est[0] = False  # sensor 0 no longer pressed
    assert not gel_press.masks_to_image_consistent(est, true, iou_min=0.5)
    # a sensor untouched at the true pose agrees only with an estimate that leaves it untouched
    true[1] = False
    np.testing.assert_array_equal(gel_press.empty_true_masks(true), [False, True])
    both = np.stack([true, true | np.eye(4, dtype=bool)[None]])
    np.testing.assert_array_equal(gel_press.masks_to_image_consistent(both, true, iou_min=0.5), [True, False])


def test_true_pose_and_a_small_error_are_consistent_a_centimetre_is_not(box):
    sensors = box_sensors(T_GT)
    near = perturbed(T_GT, [0.002, -0.001, 0.0], [0.0003, -0.0002, 0.0002])  # a fraction of a millimetre
    far = perturbed(T_GT, [0, 0, 0], [0.0, 0.0, -0.01])  # 1 cm down: the top sensor no longer touches
    result = gel_press.image_consistency(box, np.stack([T_GT, near, far]), T_GT, sensors, step=4, iou_min=0.5)
    assert result["consistent"].tolist() == [True, True, False]
    np.testing.assert_allclose(result["iou"][0], 1.0)
    assert result["iou"][1].min() > 0.7
    assert not result["empty_true"].any()


def test_a_pose_touching_a_centimetre_away_on_the_gel_is_not_consistent():
    """A thin rod across the gel: moved 1 cm along the gel it still touches, on another strip."""
    rod = trimesh.creation.cylinder(radius=0.005, height=0.1, sections=64)  # axis along z
    # the sensor presses the rod's side (+x) with its gel's long side (z) across the rod
    T_sensor = sensor_poses_touching(np.array([0.005, 0.0, 0.0]), np.array([1.0, 0, 0]), np.pi / 2, 0.0018)
    sensors = (T_GT @ T_sensor)[None]
    gel_z_in_object = T_sensor[:3, 2]  # the sensor's z axis (image rows), across the rod
    assert abs(gel_z_in_object[2]) < 1e-9
    moved = T_GT @ make_pose(np.eye(3), -0.01 * gel_z_in_object)
    depth = gel_press.poses_to_gel_depths(rod, np.stack([T_GT, moved]), sensors, step=4)
    assert (depth[1] > 0).any()  # still touching
    result = gel_press.image_consistency(rod, moved, T_GT, sensors, step=4, iou_min=0.5)
    assert not result["consistent"][0] and result["iou"][0, 0] < 0.1


def test_no_estimates_and_bad_steps(box):
    result = gel_press.image_consistency(box, np.zeros((0, 4, 4)), T_GT, box_sensors(T_GT), step=4, iou_min=0.5)
    assert result["consistent"].shape == (0,) and result["iou"].shape == (0, 3)
    with pytest.raises(Exception, match="must divide"):
        gel_press.poses_to_gel_depths(box, T_GT, box_sensors(T_GT), step=7)


# --- render-and-compare (tactile6d.estimation.render_and_compare) -----------------------------------------------------------


def test_agreement_terms_by_hand():
    obs_mask = np.zeros((1, 3, 4), dtype=bool)
    obs_mask[0, 0, :2] = True  # two cells pressed 1 mm
    obs_depth = np.where(obs_mask, 0.001, 0.0)
    pred = np.zeros((2, 1, 3, 4))
    pred[0, 0, 0, :2] = [0.001, 0.002]  # same cells, one 1 mm too deep
    pred[1, 0, 0, 1:3] = 0.001  # shifted by one cell: one shared, one missed, one in free space
    terms = render_and_compare.depths_to_agreement(obs_mask, obs_depth, pred)
    np.testing.assert_allclose(terms["iou"][:, 0], [1.0, 1 / 3])
    np.testing.assert_allclose(terms["depth_residual"][:, 0], [0.0005, 0.002 / 3])
    np.testing.assert_allclose(terms["free_space_area"][:, 0], [0.0, 1 / 12])
    np.testing.assert_allclose(terms["free_space_depth"][:, 0], [0.0, 0.001])
    cost = render_and_compare.agreement_to_cost(terms, mask_weight=1.0, depth_weight=1000.0, free_area_weight=12.0,
                                       free_depth_weight=0.0)
    np.testing.assert_allclose(cost, [0.5, 2 / 3 + 2 / 3 + 1.0])
    # a margin forgives shallow presses into free gel, and that much of deeper ones
    margin = render_and_compare.depths_to_agreement(obs_mask, obs_depth, pred, free_margin=0.0004)
    np.testing.assert_allclose(margin["free_space_depth"][:, 0], [0.0, 0.0006])
    pred[1, 0, 0, 2] = 0.0003
    margin = render_and_compare.depths_to_agreement(obs_mask, obs_depth, pred, free_margin=0.0004)
    np.testing.assert_allclose(margin["free_space_area"][:, 0], [0.0, 0.0])
    # nothing seen and nothing predicted agree perfectly
    empty = render_and_compare.depths_to_agreement(np.zeros((1, 3, 4), bool), np.zeros((1, 3, 4)), np.zeros((1, 1, 3, 4)))
    assert render_and_compare.agreement_to_cost(empty)[0] == 0.0


def test_image_to_grid_takes_block_means():
    image = np.arange(16.0).reshape(4, 4)
    np.testing.assert_allclose(render_and_compare.image_to_grid(image, 2), [[2.5, 4.5], [10.5, 12.5]])
    mask = np.zeros((2, 320, 240), dtype=bool)
    mask[1, :4, :4] = True
    grid = render_and_compare.image_to_grid(mask, 4)
    assert grid.shape == (2, 80, 60) and grid[1, 0, 0] == 1.0 and grid.sum() == 1.0
    with pytest.raises(Exception, match="must divide"):
        render_and_compare.image_to_grid(image, 3)


def _edge_box_scene():
    """A box with sensors on its top and bottom faces 5 mm from an edge and one on a side face; the
    object shifted along that edge's normal keeps every contact point on the same flat face."""
    mesh = trimesh.creation.box(extents=(0.10, 0.06, 0.04))
    p = np.array([[0.045, 0.0, 0.02], [0.045, 0.005, -0.02], [0.0, -0.03, 0.0]])
    n = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, -1.0, 0]])
    return mesh, p, n, [np.array([-0.003, 0.0, 0.0]), np.array([0.003, 0.0, 0.0])]


def _rim_cylinder_scene():
    """A cylinder with three sensors around its side 5 mm below the top rim; the object slid along its
    axis keeps every contact point on the side."""
    mesh = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=128)
    angles = np.deg2rad([0.0, 120.0, 240.0])
    n = np.stack([np.cos(angles), np.sin(angles), np.zeros(3)], axis=1)
    p = 0.03 * n + [0.0, 0.0, 0.045]
    return mesh, p, n, [np.array([0.0, 0.0, -0.003]), np.array([0.0, 0.0, 0.003])]


@pytest.mark.parametrize("make_scene", [_edge_box_scene, _rim_cylinder_scene], ids=["box", "cylinder"])
def test_render_and_compare_prefers_the_true_pose_where_the_point_loss_cannot(make_scene):
    mesh, p, n, shifts = make_scene()
    sensors = T_GT @ sensor_poses_touching(p, n, [0.3, -0.5, 1.2], 0.0018)
    poses = np.stack([T_GT] + [T_GT @ make_pose(np.eye(3), s) for s in shifts])

    # The pair-distance loss with each pose's best tuple (the sensors' landmarks snapped to the surface)
    # is the same for the true and the shifted poses.
    s_world = sensor.contact_points(sensors)
    tuples = np.stack([mesh.nearest.on_surface((invert_pose(T)[:3, :3] @ s_world.T).T + invert_pose(T)[:3, 3])[0]
                       for T in poses])
    losses = optimize.poses_to_losses(poses, tuples, s_world)
    assert losses[1:] == pytest.approx([losses[0]] * 2, abs=1e-7)

    # What the sensors see at the true pose, a little degraded as an estimate from images would be: depth
    # 10 % shallow with noise, the mask thresholded so that the faintest rim is lost.
    step = 4
    true_depth = gel_press.poses_to_gel_depths(mesh, T_GT, sensors, step)[0]
    rng = np.random.default_rng(0)
    observed_depth = np.clip(0.9 * true_depth + rng.normal(0, 5e-5, true_depth.shape), 0, None) * (true_depth > 0)
    observed_mask = observed_depth > 1e-4
    for free_margin in (0.0, 1e-4):
        terms = render_and_compare.poses_to_agreement(mesh, poses, sensors, observed_mask, observed_depth, step, free_margin)
        cost = render_and_compare.agreement_to_cost(terms)
        assert cost[0] < cost[1:].min()
    assert (terms["iou"][0] > terms["iou"][1:].min(axis=0)).any()
    # sliding toward the edge or rim shrinks a patch; away from it, the object presses gel the image shows free
    assert terms["free_space_area"][2].max() > terms["free_space_area"][0].max()
    np.testing.assert_array_equal(terms["predicted_depth"][0], true_depth)

