import numpy as np
import pytest
import trimesh

from tactile6d import gel_contact, sensor
from tactile6d.geometry import invert_pose, make_pose, rotvec_to_rotmat
from tactile6d.meshes import make_primitive
from tactile6d.render import DigitRenderer, mesh_arrays
from tactile6d.sensor import sensor_poses_touching

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


@pytest.mark.parametrize("step", [4, 8])
def test_depth_equals_the_renderers_on_the_same_grid(box, step):
    rounded = make_primitive("prim_rounded_box")
    renderer = DigitRenderer(np.zeros((320, 240, 3), np.uint8), render_step=step, strict=False, noise_std=0.0)
    rng = np.random.default_rng(0)
    for mesh in (box, rounded):
        sensors = box_sensors(T_GT) if mesh is box else T_GT @ sensor_poses_touching(
            np.array([[0.0, 0.0, 0.025], [0.032, 0.022, 0.017] + 0.008 / np.sqrt(3), [0.0, -0.03, 0.0]]),
            np.array([[0, 0, 1.0], [1.0, 1.0, 1.0], [0, -1.0, 0]]), 0.3, 0.0018)
        # small and large errors: touching, penetrating deep into the body (strict=False), far away
        poses = np.stack([T_GT] + [perturbed(T_GT, rng.normal(0, 0.05, 3), rng.normal(0, 0.004, 3))
                                   for _ in range(4)]
                         + [perturbed(T_GT, [0, 0, 0], [0, 0, 0.006]), perturbed(T_GT, [0, 0, 0], [0, 0, -0.01])])
        depth = gel_contact.poses_to_gel_depths(mesh, poses, sensors, step=step)
        assert depth.shape == (len(poses), 3, 320 // step, 240 // step) and depth.dtype == np.float32
        arrays = mesh_arrays(mesh)
        for p, T in enumerate(poses):
            for i, T_sensor in enumerate(sensors):
                _, expected = renderer.contact(arrays, invert_pose(T_sensor) @ T)
                np.testing.assert_array_equal(depth[p, i], expected)
        assert (depth[0] > 0).any(axis=(1, 2)).all()  # every sensor touches at the true pose
        assert depth[5, 0].max() > renderer.max_press  # the top sensor pressed into the body


def test_depth_on_a_flat_face_is_the_gel_minus_the_plane():
    """Naive reference: a sensor square on a big flat face, the face plane at x = apex - press."""
    mesh = trimesh.creation.box(extents=(0.2, 0.2, 0.05))
    press = 0.0015
    T_sensor = sensor_poses_touching(np.array([0.0, 0.0, 0.025]), np.array([0, 0, 1.0]), 0.0, press)
    depth = gel_contact.poses_to_gel_depths(mesh, np.eye(4), T_sensor[None], step=8)[0, 0]
    grid = gel_contact.gel_grid(8)
    plane_x = sensor.GEL_CENTER[0] - press
    # the ray (1, u, v) from the camera meets the plane at camera-axis distance plane_x
    expected = np.maximum(grid.gel_t - plane_x, 0.0).reshape(grid.shape)
    np.testing.assert_allclose(depth, expected, atol=1e-6)
    assert depth.max() == pytest.approx(press, abs=1e-5)  # the rays nearest the apex
    assert 0 < (depth > 0).mean() < 1  # a pressed disc, not the whole gel


def test_mask_iou_by_hand():
    a = np.zeros((2, 4, 4), dtype=bool)
    b = np.zeros((2, 4, 4), dtype=bool)
    a[0, :2, :2] = True  # 4 cells
    b[0, 1:3, :2] = True  # 4 cells, 2 shared: IoU 2 / 6
    a[1, 0, 0] = True  # no overlap with an empty mask: 0
    np.testing.assert_allclose(gel_contact.mask_iou(a, b), [2 / 6, 0.0])
    assert gel_contact.mask_iou(np.zeros((3, 3), bool), np.zeros((3, 3), bool)) == 1.0
    assert gel_contact.mask_iou(a[0], a[0]) == 1.0


def test_masks_to_image_consistent_needs_every_sensor():
    true = np.zeros((2, 4, 4), dtype=bool)
    true[:, :2, :2] = True
    est = true.copy()
    est[1, 2, :2] = True  # sensor 1: IoU 4 / 6
    assert gel_contact.masks_to_image_consistent(est, true)
    assert not gel_contact.masks_to_image_consistent(est, true, iou_min=0.7)
    est[0] = False  # sensor 0 no longer pressed
    assert not gel_contact.masks_to_image_consistent(est, true)
    # a sensor untouched at the true pose agrees only with an estimate that leaves it untouched
    true[1] = False
    np.testing.assert_array_equal(gel_contact.empty_true_masks(true), [False, True])
    both = np.stack([true, true | np.eye(4, dtype=bool)[None]])
    np.testing.assert_array_equal(gel_contact.masks_to_image_consistent(both, true), [True, False])


def test_true_pose_and_a_small_error_are_consistent_a_centimetre_is_not(box):
    sensors = box_sensors(T_GT)
    near = perturbed(T_GT, [0.002, -0.001, 0.0], [0.0003, -0.0002, 0.0002])  # a fraction of a millimetre
    far = perturbed(T_GT, [0, 0, 0], [0.0, 0.0, -0.01])  # 1 cm down: the top sensor no longer touches
    result = gel_contact.image_consistency(box, np.stack([T_GT, near, far]), T_GT, sensors)
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
    depth = gel_contact.poses_to_gel_depths(rod, np.stack([T_GT, moved]), sensors)
    assert (depth[1] > 0).any()  # still touching
    result = gel_contact.image_consistency(rod, moved, T_GT, sensors)
    assert not result["consistent"][0] and result["iou"][0, 0] < 0.1


def test_no_estimates_and_bad_steps(box):
    result = gel_contact.image_consistency(box, np.zeros((0, 4, 4)), T_GT, box_sensors(T_GT))
    assert result["consistent"].shape == (0,) and result["iou"].shape == (0, 3)
    with pytest.raises(Exception, match="must divide"):
        gel_contact.gel_grid(7)
