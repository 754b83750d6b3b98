"""tactile6d.perception.contact_patch: contact point, normal, press depth and mask from one tactile image and its no-contact image.

Contacts are rendered by the simulator on superquadrics with known geometry; the calibration is a small
one made once per module (the default is larger and more accurate).
"""

import cv2
import numpy as np
import pytest
from test_estimator import small_patch_model

from tactile6d.core import sensor
from tactile6d.core.errors import DataError, InputError
from tactile6d.perception import contact_patch
from tactile6d.sim import superquadrics as sq
from tactile6d.sim.render import CAMERA_POSITION, DigitRenderer, pixel_rays

H, W = sensor.IMAGE_HEIGHT, sensor.IMAGE_WIDTH
SPHERE = sq.Superquadric(0.010, 0.010, 0.010, 1.0, 1.0)
BOX = sq.Superquadric(0.030, 0.030, 0.030, 0.1, 0.1)
TILT = np.deg2rad(20.0)
OFFSET = 0.004


@pytest.fixture(scope="module")
def model():
    return small_patch_model()


def smooth_background() -> np.ndarray:
    """A smooth synthetic BGR background unlike the calibration's flat grey (the method must not care)."""
    rows, cols = np.mgrid[0:H, 0:W]
    return np.stack([70 + cols // 4, 90 + rows // 6, 120 + 0 * rows], axis=-1).astype(np.uint8)


@pytest.fixture(scope="module")
def background():
    return smooth_background()


@pytest.fixture(scope="module")
def renderer(background):
    return DigitRenderer.from_default_config(background)


@pytest.fixture(scope="module")
def no_contact(renderer):
    return renderer.no_contact(seed=12345)


@pytest.fixture(scope="module")
def mesh_of():
    cache = {}

    def get(shape):
        if shape not in cache:
            cache[shape] = contact_patch.shape_to_mesh(shape)
        return cache[shape]

    return get


def press(renderer, mesh_of, shape, point, normal, depth=0.0018, roll=0.3, tilt_axis=0.0, tilt=0.0, offset=(0.0, 0.0),
          seed=0):
    """Render a press; -> (RenderResult, true contact point (3,), true normal (3,) in the sensor frame, T_object_sensor)."""
    mesh = mesh_of(shape)
    T = contact_patch.tilted_sensor_pose(point, normal, roll, tilt_axis, tilt, offset)
    T = contact_patch.press_to_depth(renderer, mesh, T, depth)
    result = renderer.render(mesh, np.eye(4), T, seed=seed)
    normals = contact_patch.true_normals(shape, T, result.depth)
    point_true, normal_true = contact_patch.depth_to_contact(result.depth, normals)
    return result, point_true, normal_true, T


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0)))


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


# --- the convention ---------------------------------------------------------------------------------------


def test_square_press_on_a_flat_face_gives_the_landmark_and_minus_x(renderer, mesh_of, model, no_contact):
    """The standard contact (face pressed 1.8 mm square into the gel apex) sits at the landmark, normal -x."""
    result, _, _, _ = press(renderer, mesh_of, BOX, [-0.03, 0.0, 0.0], [-1.0, 0.0, 0.0])
    est = contact_patch.image_to_patch(result.image, no_contact, model)
    assert est.contact
    landmark = sensor.contact_points(np.eye(4))
    # the surface point on the gel axis is 2 mm - 1.8 mm beyond the landmark
    assert np.linalg.norm(est.point - landmark) < 0.0005
    assert abs(est.point[0] - (sensor.GEL_CENTER[0] - 0.0018)) < 0.0002
    assert angle_deg(est.normal, [-1.0, 0.0, 0.0]) < 1.5
    assert abs(est.depth.max() - 0.0018) < 0.0002
    assert iou(est.mask, result.mask) > 0.9
    assert est.mask.shape == (H, W) and est.mask.dtype == bool
    assert est.depth.shape == (H, W) and est.depth.dtype == np.float32
    assert np.all(est.depth[~est.mask] == 0.0)


def test_depth_to_contact_is_the_deepest_surface_point_for_a_paraboloid():
    """A synthetic press deepest at one pixel: the contact is the surface point there, the normal given."""
    rays = pixel_rays(W, H)
    row, col = 100, 150
    r2 = (np.arange(H)[:, None] - row) ** 2 + (np.arange(W)[None, :] - col) ** 2
    depth = np.clip(0.002 - 2e-7 * r2, 0.0, None).astype(np.float32)
    normals = np.zeros((H, W, 3))
    normals[..., 0] = -1.0
    point, normal = contact_patch.depth_to_contact(depth, normals)
    expected = CAMERA_POSITION + (contact_patch.gel_distance()[row, col] - 0.002) * rays[row, col]
    assert np.linalg.norm(point - expected) < 5e-5
    np.testing.assert_allclose(normal, [-1.0, 0.0, 0.0])
    assert contact_patch.depth_to_contact(np.zeros((H, W), np.float32), normals) == (None, None)


def test_integrating_true_normals_recovers_the_true_depth(renderer, mesh_of):
    """The log-depth integration alone (exact normals, exact mask) gives back the renderer's depth."""
    result, _, _, T = press(renderer, mesh_of, SPHERE, [0.0, 0.0, -0.01], [0.0, 0.0, -1.0], tilt=0.2,
                            offset=(0.002, -0.003))
    normals = contact_patch.true_normals(SPHERE, T, result.depth)
    depth = contact_patch.normals_to_depth(normals, result.mask, 4)
    pressed = result.mask
    assert abs(depth.max() - result.depth.max()) < 1e-4
    assert np.median(np.abs(depth[pressed] - result.depth[pressed])) < 5e-5


# --- known contacts, off-centre and tilted ----------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_sphere_off_centre_and_tilted(renderer, mesh_of, model, no_contact, seed):
    rng = np.random.default_rng(seed)
    result, p_true, n_true, _ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0],
                                   depth=rng.uniform(0.0015, 0.002), roll=rng.uniform(-np.pi, np.pi),
                                   tilt_axis=rng.uniform(-np.pi, np.pi), tilt=TILT * rng.uniform(0.5, 1.0),
                                   offset=rng.uniform(-OFFSET, OFFSET, 2), seed=seed)
    est = contact_patch.image_to_patch(result.image, no_contact, model)
    assert est.contact
    landmark_error = np.linalg.norm(sensor.CONTACT_POINT - p_true)
    assert landmark_error > 0.001  # the press really is off the landmark
    assert np.linalg.norm(est.point - p_true) < 0.0005
    assert angle_deg(est.normal, n_true) < 3.0
    assert iou(est.mask, result.mask) > 0.9


@pytest.mark.parametrize("seed", [4, 5])
def test_box_face_off_centre_and_tilted(renderer, mesh_of, model, no_contact, seed):
    """A flat face: the deepest press moves where the gel's slope matches the face, off the centre."""
    rng = np.random.default_rng(seed)
    result, p_true, n_true, _ = press(renderer, mesh_of, BOX, [-0.03, 0.005, -0.004], [-1.0, 0.0, 0.0],
                                   depth=rng.uniform(0.0015, 0.002), roll=rng.uniform(-np.pi, np.pi),
                                   tilt_axis=rng.uniform(-np.pi, np.pi), tilt=np.deg2rad(8.0),
                                   offset=rng.uniform(-OFFSET, OFFSET, 2), seed=seed)
    est = contact_patch.image_to_patch(result.image, no_contact, model)
    assert np.linalg.norm(sensor.CONTACT_POINT[1:] - p_true[1:]) > 0.002
    assert angle_deg(n_true, [-1.0, 0.0, 0.0]) > 7.0  # tilted: the old -x assumption is off by the tilt
    assert np.linalg.norm(est.point - p_true) < 0.0005
    assert angle_deg(est.normal, n_true) < 2.0
    assert iou(est.mask, result.mask) > 0.9


def test_box_edge_off_centre_and_tilted(renderer, mesh_of, model, no_contact):
    direction = np.array([-1.0, -1.0, 0.0])
    point = sq.project_to_surface(BOX, direction[None])[0]
    normal = sq.surface_normals(BOX, point[None])[0]
    result, p_true, n_true, _ = press(renderer, mesh_of, BOX, point, normal, roll=1.0, tilt_axis=0.7,
                                   tilt=np.deg2rad(15.0), offset=(0.003, -0.002), seed=7)
    est = contact_patch.image_to_patch(result.image, no_contact, model)
    assert est.contact
    assert np.linalg.norm(est.point - p_true) < 0.001
    assert angle_deg(est.normal, n_true) < 5.0
    assert iou(est.mask, result.mask) > 0.85


def test_another_units_background(data_dir, mesh_of, model):
    """Rendered over TACTO's no-contact image and estimated with it: the difference image carries over."""
    bg = cv2.imread(str(data_dir / "digit" / "tacto" / "bg_digit_240_320.jpg"))
    if bg is None:
        pytest.skip("TACTO's background image is not in the data directory")
    other = DigitRenderer.from_default_config(bg)
    result, p_true, n_true, _ = press(other, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], tilt_axis=2.0,
                                   tilt=0.25, offset=(-0.002, 0.003), seed=9)
    est = contact_patch.image_to_patch(result.image, other.no_contact(seed=77), model)
    assert np.linalg.norm(est.point - p_true) < 0.0005
    assert angle_deg(est.normal, n_true) < 3.0
    assert iou(est.mask, result.mask) > 0.9


# --- no contact, bad input ----------------------------------------------------------------------------------


# --- moving a contact to the image centre -----------------------------------------------------------------


def test_point_to_pixel_inverts_pixel_rays():
    rays = pixel_rays(W, H)
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, H, 50), rng.integers(0, W, 50)
    points = CAMERA_POSITION + rng.uniform(0.01, 0.03, (50, 1)) * rays[rows, cols]
    np.testing.assert_allclose(contact_patch.point_to_pixel(points), np.stack([rows + 0.5, cols + 0.5], axis=1), atol=1e-9)
    np.testing.assert_allclose(contact_patch.point_to_pixel(sensor.CONTACT_POINT), [H / 2, W / 2], atol=1e-9)


def test_shift_difference_moves_only_the_difference(no_contact):
    image = no_contact.copy()
    image[100:120, 50:60] = 255 - no_contact[100:120, 50:60]
    moved = contact_patch.shift_difference(image, no_contact, 30, -20)
    diff = image.astype(int) - no_contact
    moved_diff = np.clip(no_contact[130:150, 30:40].astype(int) + diff[100:120, 50:60], 0, 255) - no_contact[130:150, 30:40]
    np.testing.assert_array_equal(moved[130:150, 30:40].astype(int) - no_contact[130:150, 30:40], moved_diff)
    outside = np.ones((H, W), dtype=bool)
    outside[130:150, 30:40] = False
    np.testing.assert_array_equal(moved[outside], no_contact[outside])  # nothing else changed
    np.testing.assert_array_equal(contact_patch.shift_difference(image, no_contact, 0, 0), image)
    np.testing.assert_array_equal(contact_patch.shift_difference(image, no_contact, H, 0), no_contact)  # moved out of view


def test_centre_contact_puts_an_off_centre_press_at_the_centre(renderer, mesh_of, model, no_contact):
    result, p_true, _, _ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0],
                                 offset=(0.004, -0.003), seed=7)
    off = contact_patch.image_to_patch(result.image, no_contact, model)
    assert np.linalg.norm(contact_patch.point_to_pixel(off.point) - [H / 2, W / 2]) > 20  # really off-centre
    centred = contact_patch.image_to_patch(contact_patch.centre_contact(result.image, no_contact, off.point), no_contact, model)
    assert centred.contact
    assert np.linalg.norm(contact_patch.point_to_pixel(centred.point) - [H / 2, W / 2]) < 2.0
    assert abs(centred.mask.sum() / off.mask.sum() - 1.0) < 0.1  # the same press, moved


def test_read_angles_centres_only_contacts_read_from_images(renderer, mesh_of, model, no_contact):
    from tactile6d.core.config import compose_config
    from tactile6d.core.settings import SelectSettings
    from tactile6d.perception.contacts import patches_to_contacts
    from tactile6d.perception.encode import read_angles

    result, *_ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], offset=(-0.004, 0.002), seed=8)
    images = np.stack([result.image, renderer.no_contact(seed=9)])
    T = np.stack([np.eye(4), np.eye(4)])
    T[:, :3, 3] = [[0.1, 0.0, 0.2], [0.0, 0.1, 0.2]]
    contacts = patches_to_contacts([contact_patch.image_to_patch(im, no_contact, model) for im in images], T)
    assert contacts.from_patch.tolist() == [True, False]
    seen = []

    def encoder(batch):
        seen.append(np.array(batch))
        return np.arange(len(batch), dtype=float)

    on = SelectSettings.from_cfg(compose_config(["select.contacts=patch", "select.centre_images=true"]).select)
    np.testing.assert_array_equal(read_angles(encoder, on, images, contacts, T, no_contact), [0.0, 1.0])
    centred = contact_patch.image_to_patch(seen[-1][0], no_contact, model)
    assert np.linalg.norm(contact_patch.point_to_pixel(centred.point) - [H / 2, W / 2]) < 2.0
    np.testing.assert_array_equal(seen[-1][1], images[1])  # no contact read: left as it is
    off = SelectSettings.from_cfg(compose_config(["select.contacts=patch", "select.centre_images=false"]).select)
    read_angles(encoder, off, images, contacts, T, no_contact)
    np.testing.assert_array_equal(seen[-1], images)
    landmark = SelectSettings.from_cfg(compose_config(["select.contacts=landmark", "select.centre_images=true"]).select)
    assert not landmark.centres_images


def test_no_contact_image_gives_an_explicit_no_contact(renderer, model, no_contact):
    for image in (renderer.no_contact(seed=3), no_contact):
        est = contact_patch.image_to_patch(image, no_contact, model)
        assert est.contact is False
        assert est.point is None and est.normal is None
        assert not est.mask.any() and not est.depth.any()
        assert np.isfinite(est.noise)


def test_saturated_or_blank_images_raise_one_clear_error_or_report_no_contact(model, no_contact):
    for value in (0, 255):
        image = np.full((H, W, 3), value, dtype=np.uint8)
        with pytest.raises(InputError, match="saturated"):
            contact_patch.image_to_patch(image, no_contact, model)
    grey = np.full((H, W, 3), 128, dtype=np.uint8)
    est = contact_patch.image_to_patch(grey, grey, model)
    assert est.contact is False and est.point is None


@pytest.mark.parametrize(
    "image, background, match",
    [
        (np.zeros((H, W, 3), np.float32), np.zeros((H, W, 3), np.uint8), "dtype"),
        (np.zeros((W, H, 3), np.uint8), np.zeros((H, W, 3), np.uint8), "shape"),
        (np.zeros((H, W), np.uint8), np.zeros((H, W, 3), np.uint8), "shape"),
        (np.zeros((H, W, 3), np.uint8), np.zeros((160, 120, 3), np.uint8), "no-contact image has shape"),
        (np.zeros((H, W, 3), np.uint8), np.zeros((H, W, 3), np.int64), "no-contact image has dtype"),
    ],
)
def test_bad_inputs_raise_input_error(model, image, background, match):
    with pytest.raises(InputError, match=match):
        contact_patch.image_to_patch(image, background, model)


# --- calibration --------------------------------------------------------------------------------------------


def test_model_round_trip_and_determinism(tmp_path, renderer, mesh_of, model, no_contact):
    result, _, _, _ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], seed=11)
    path = contact_patch.save_model(model, tmp_path / "patch_model.npz")
    loaded = contact_patch.load_model(path)
    a = contact_patch.image_to_patch(result.image, no_contact, model)
    b = contact_patch.image_to_patch(result.image, no_contact, loaded)
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.point, b.point)
    np.testing.assert_array_equal(loaded.coefficients, model.coefficients)
    for name in contact_patch.PatchModel.__dataclass_fields__:
        if name != "coefficients":
            assert getattr(loaded, name) == getattr(model, name)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(DataError, match="calibration"):
        contact_patch.load_model(tmp_path / "other.npz")
    with pytest.raises(DataError):
        contact_patch.load_model(tmp_path / "missing.npz")


def test_fit_model_needs_a_contact():
    grey = np.full((1, H, W, 3), 128, dtype=np.uint8)
    with pytest.raises(DataError, match="no calibration image"):
        contact_patch.fit_model(grey, grey[0], np.zeros((1, H, W, 3)), np.zeros((1, H, W)))
