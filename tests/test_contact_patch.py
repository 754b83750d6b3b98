"""tactile6d.perception.contact_patch: contact point, normal, press depth and mask from one tactile image and its no-contact image.

Contacts are rendered by the simulator on superquadrics with known geometry; the calibration is a small
one made once per module (the default is larger and more accurate).
"""

import warnings

import cv2
import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg
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


def test_normals_whose_integral_runs_away_give_finite_depths():
    """Normals that integrate to a gel distance over e^100 m (a pyramid of log-slope 2 a pixel, inward) must
    give finite depths, no warning: before the cap, the float32 cast made the peak infinite and bilinear
    interpolation spread NaN over the whole mask."""
    rays = np.moveaxis(contact_patch._geometry_planes()[0], 0, -1)
    rows, cols = np.mgrid[0:H, 0:W]
    g_col, g_row = 2.0 * np.sign(cols - (W - 1) / 2), 2.0 * np.sign(rows - (H - 1) / 2)
    # d log t / d column = -n_y / (f n.r) (and n_z for rows): pick n.r = -c, solve n_x, normalise.
    c = 0.01
    n_y, n_z = g_col * contact_patch._FOCAL * c, g_row * contact_patch._FOCAL * c
    n_x = (-c - n_y * rays[..., 1] - n_z * rays[..., 2]) / rays[..., 0]
    normals = np.stack([n_x, n_y, n_z], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    mask = np.zeros((H, W), bool)
    mask[100:220, 60:180] = True
    np.testing.assert_allclose(contact_patch.normals_to_log_gradients(normals)[0][mask], -g_col[mask])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        depth = contact_patch.normals_to_depth(normals, mask, 4)
    assert np.isfinite(depth).all() and depth.min() >= 0.0
    assert (depth[mask] == 0.0).mean() > 0.9  # the runaway centre is no press


# --- known contacts, off-centre and tilted ----------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.slow
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


@pytest.mark.slow
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


# --- noise that is not white: a camera's JPEG stream, a lens out of focus ----------------------------------


def _naive_far_residual_noise(smooth, d):
    """The per-pixel loop over every second row and column that far_residual_noise vectorises."""
    residuals = []
    for r in range(d, smooth.shape[0] - d, 2):
        for c in range(d, smooth.shape[1] - d, 2):
            around = (smooth[r - d, c] + smooth[r + d, c]) + (smooth[r, c - d] + smooth[r, c + d])
            residuals.extend(np.abs(smooth[r, c] - np.float32(0.25) * around))
    return float(1.4826 * np.median(np.asarray(residuals, np.float32)) / np.sqrt(1.25))


@pytest.mark.parametrize("d", [3, 6])
def test_far_residual_noise_is_the_naive_loop(d):
    rng = np.random.default_rng(d)
    smooth = rng.normal(0.0, 2.0, (40, 30, 3)).astype(np.float32)
    assert contact_patch.far_residual_noise(smooth, d) == pytest.approx(_naive_far_residual_noise(smooth, d), rel=1e-6)


def test_white_noise_keeps_the_white_noise_formula_and_blurred_noise_is_measured(no_contact):
    """White noise (the renderer's): the level is the formula's, bit for bit, so masks stay as they were. The
    same noise blurred (sigma 1 pixel) before it reaches D: the formula says about a tenth of the smoothed D's
    noise; the measure used instead is within 20 % of it."""
    rng = np.random.default_rng(0)
    base = np.full((H, W, 3), 120.0)
    white = np.clip(np.rint(base + rng.normal(0, 7, base.shape)), 0, 255).astype(np.uint8)
    diff = contact_patch.images_to_difference(white, no_contact)
    smooth = contact_patch.smooth_difference(diff, 2.0)
    noise = contact_patch.difference_to_noise(diff)
    assert contact_patch.smoothed_difference_noise(smooth, noise, 2.0) == contact_patch.smoothed_noise(noise, 2.0)
    blurred_noise = cv2.GaussianBlur(rng.normal(0, 7, base.shape), (7, 7), 1.0)
    image = np.clip(np.rint(no_contact + blurred_noise), 0, 255).astype(np.uint8)
    diff = contact_patch.images_to_difference(image, no_contact)
    smooth = contact_patch.smooth_difference(diff, 2.0)
    noise = contact_patch.difference_to_noise(diff)
    actual = float(smooth.std())
    assert contact_patch.smoothed_noise(noise, 2.0) < 0.3 * actual
    assert contact_patch.smoothed_difference_noise(smooth, noise, 2.0) == pytest.approx(actual, rel=0.2)


@pytest.mark.parametrize("camera", ["jpeg80", "jpeg60", "blur1"])
def test_a_press_through_a_cameras_stream_reads_as_the_clean_press(renderer, mesh_of, model, no_contact, camera):
    """The image and the no-contact image both through a JPEG stream or a lens out of focus
    (``perturb.through_camera``'s changes): the mask stays the press's (it covered the whole image when the
    white-noise formula set its threshold), the contact point within 0.5 mm of the clean read, and an
    untouched image through the same camera shows no contact."""
    from tactile6d.sim import perturb

    through = {"jpeg80": lambda x: perturb.jpeg_round_trip(x, 80), "jpeg60": lambda x: perturb.jpeg_round_trip(x, 60),
               "blur1": lambda x: perturb.defocus(x, 1.0)}[camera]
    result, _, _, _ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], seed=7)
    clean = contact_patch.image_to_patch(result.image, no_contact, model)
    read = contact_patch.image_to_patch(through(result.image), through(no_contact), model)
    assert read.contact and iou(read.mask, clean.mask) > 0.8
    assert np.linalg.norm(read.point - clean.point) < 0.0005
    untouched = contact_patch.image_to_patch(through(renderer.no_contact(seed=3)), through(no_contact), model)
    assert untouched.contact is False


@pytest.mark.parametrize("noise_std", [0.0, 2.0])
def test_a_quiet_image_gets_the_mask_of_the_renderers_noise(background, mesh_of, model, noise_std):
    """Rendered with less noise than the renderer's 7 grey levels, a press's mask is about the one read under
    that noise, not grown into the blurred imprint's faint halo, as it was with thresholds that fell with the
    noise (``MIN_NOISE``)."""
    noisy = DigitRenderer.from_default_config(background)
    quiet = DigitRenderer.from_default_config(background, noise_std=noise_std)
    reads = {}
    for name, renderer in (("noisy", noisy), ("quiet", quiet)):
        result, _, _, _ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], seed=5)
        reads[name] = contact_patch.image_to_patch(result.image, renderer.no_contact(seed=6), model)
    truth = result.mask
    assert iou(reads["quiet"].mask, reads["noisy"].mask) > 0.9
    assert reads["quiet"].mask.sum() < 1.1 * reads["noisy"].mask.sum()
    assert iou(reads["quiet"].mask, truth) > 0.85


def dust(image: np.ndarray, centres, depth: float = 60.0, radius: float = 2.5) -> np.ndarray:
    """image (H, W, 3) uint8 with dark Gaussian specks (``depth`` grey levels, ``radius`` px) at ``centres`` (row,
    column): dust settled on the gel after its no-contact image was recorded."""
    rows, cols = np.mgrid[0:H, 0:W]
    out = image.astype(np.float64)
    for r, c in centres:
        out -= depth * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2.0 * radius**2))[..., None]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


SPECKS = [(40, 40), (280, 200), (60, 190), (260, 50)]  # near the gel's corners, away from the press


def test_dust_on_the_gel_is_left_out_of_the_contact_mask(renderer, background, mesh_of, model, monkeypatch):
    """Four dark specks away from a press, read against a recorded (noise-free) no-contact image: the mask is the
    press's alone (``SPECK_FRACTION``), not its convex hull with the specks across the gel; with the specks kept
    (the fraction 0) it is that hull."""
    no_contact = DigitRenderer.from_default_config(background, noise_std=0.0).no_contact()
    result, _, _, _ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], depth=0.0012, seed=5)
    clean = contact_patch.image_to_patch(result.image, no_contact, model)
    dusty = contact_patch.image_to_patch(dust(result.image, SPECKS), no_contact, model)
    assert clean.contact and dusty.contact
    assert iou(dusty.mask, clean.mask) > 0.95
    assert np.linalg.norm(dusty.point - clean.point) < 0.0003
    monkeypatch.setattr(contact_patch, "SPECK_FRACTION", 0.0)
    kept = contact_patch.image_to_patch(dust(result.image, SPECKS), no_contact, model)
    assert iou(kept.mask, clean.mask) < 0.5


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
        (np.zeros((W, H, 3), np.uint8), np.zeros((H, W, 3), np.uint8), "rotated by 90 degrees"),
        (np.zeros((H, W), np.uint8), np.zeros((H, W, 3), np.uint8), "shape"),
        (np.zeros((H, W, 3), np.uint8), np.zeros((160, 120, 3), np.uint8), "no-contact image is 120 wide x 160 high"),
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


# --- the computation on a box around the mask is the whole-image one, bit for bit --------------------------
#
# image_to_patch runs the per-pixel steps on a box around the mask and takes shortcuts that must not move a
# bit (see contact_patch, "the region the per-pixel work is done on"). The reference below is the plain
# whole-image computation those steps replaced, kept verbatim; every output must be the same bits, but for
# the depth integration's solve: the library solves the normal equations by a banded Cholesky
# factorisation, the reference by a general sparse LU, so the depths agree to rounding (a few float32 ulps).
# The library's own routes (the box in image_to_patch, the whole image in the public steps) agree bit for bit.


def _reference_difference(image, no_contact):
    img, bg = contact_patch.check_image(image), contact_patch.check_image(no_contact)
    clipped = ((img == 0) & (bg != 0)) | ((img == 255) & (bg != 255))
    if np.mean(np.any(clipped, axis=-1)) > contact_patch._MAX_SATURATED_FRACTION:
        raise InputError("saturated")
    return img.astype(np.float32) - bg.astype(np.float32)


def _reference_noise(diff):
    lap = diff[1:-1, 1:-1] - 0.25 * (diff[:-2, 1:-1] + diff[2:, 1:-1] + diff[1:-1, :-2] + diff[1:-1, 2:])
    return float(1.4826 * np.median(np.abs(lap)) / np.sqrt(1.25))


def _reference_mask(smooth, noise, model):
    s = max(contact_patch.smoothed_difference_noise(smooth, noise, model.mask_sigma),
            contact_patch.smoothed_noise(contact_patch.MIN_NOISE, model.mask_sigma))
    magnitude = np.sqrt(np.sum(smooth.astype(np.float64) ** 2, axis=-1))
    low = (magnitude > model.grow_level * s).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(low, connectivity=8)
    if count <= 1:
        return np.zeros(magnitude.shape, dtype=bool)
    peak = np.zeros(count)
    np.maximum.at(peak, labels.ravel(), magnitude.ravel())
    keep = (peak > model.seed_level * s) & (stats[:, cv2.CC_STAT_AREA] >= model.min_area)
    keep[0] = False
    mask = keep[labels].astype(np.uint8)
    if not mask.any():
        return mask.astype(bool)
    mask = contact_patch._convex_hull(mask).astype(np.uint8)
    size = 2 * int(model.erode) + 1
    return cv2.erode(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))).astype(bool)


def _reference_features(colour, rays, degree, colour_scale):
    x = np.concatenate([np.asarray(colour, np.float64) / colour_scale, 2.0 * np.asarray(rays)[:, 1:3]], axis=1)
    exps = contact_patch._monomial_exponents(x.shape[1], degree)
    powers = np.ones((x.shape[1], degree + 1, len(x)))
    for p in range(1, degree + 1):
        powers[:, p] = powers[:, p - 1] * x.T
    feats = np.ones((len(x), len(exps)))
    for k, e in enumerate(exps):
        for i in np.flatnonzero(e):
            feats[:, k] *= powers[i, e[i]]
    return feats


def _reference_lateral_to_normals(lateral):
    lat = np.asarray(lateral, dtype=np.float64)
    r = np.linalg.norm(lat, axis=1, keepdims=True)
    lat = np.where(r > contact_patch._MAX_LATERAL, lat * (contact_patch._MAX_LATERAL / np.maximum(r, 1e-12)), lat)
    nx = -np.sqrt(1.0 - np.sum(lat**2, axis=1))
    return np.concatenate([nx[:, None], lat], axis=1)


def _reference_normals(smooth, mask, model):
    k = 2
    _, _, gel_normals = contact_patch._camera_geometry()
    block_rays, block_gel = contact_patch._block_geometry(k)
    block_mask = contact_patch._block_mean(mask.astype(np.float32), k) > 0.0
    block_normals = block_gel.copy()
    block_depth = np.zeros(block_mask.shape)
    if block_mask.any():
        colour = contact_patch._block_mean(smooth, k)[block_mask]
        feats = _reference_features(colour, block_rays[block_mask], model.degree, model.colour_scale)
        pred = feats @ model.coefficients
        block_normals[block_mask] = _reference_lateral_to_normals(pred[:, :2])
        block_depth[block_mask] = np.clip(pred[:, 2] * 1e-3, 0.0, None)
    up = cv2.resize(block_normals.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR).astype(np.float64)
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    normals = np.where(mask[..., None], up, gel_normals)
    depth = np.where(mask, cv2.resize(block_depth.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR), 0.0)
    return normals, depth


def _reference_log_gradients(normals):
    rays = contact_patch._camera_geometry()[0]
    n_dot_r = np.minimum(np.sum(normals * rays, axis=-1), -1e-3)
    scale = -1.0 / contact_patch._FOCAL
    return (-normals[..., 1] / n_dot_r) * scale, (-normals[..., 2] / n_dot_r) * scale


def _reference_depth(normals, mask, k, prior):
    block_mean = contact_patch._block_mean
    _, t_gel, _ = contact_patch._camera_geometry()
    depth = np.zeros(mask.shape, dtype=np.float32)
    gc, gr = _reference_log_gradients(normals)
    gc, gr = block_mean(gc, k) * k, block_mean(gr, k) * k
    coarse_mask = block_mean(mask.astype(np.float64), k) > 0.0
    log_gel = np.log(block_mean(t_gel, k))
    h, w = coarse_mask.shape
    index = -np.ones((h, w), dtype=np.int64)
    index[coarse_mask] = np.arange(int(coarse_mask.sum()))
    n = int(coarse_mask.sum())
    rows, cols, vals, rhs = [], [], [], []
    eq = 0
    for axis, g in ((1, gc), (0, gr)):
        a_idx = index[:, :-1] if axis == 1 else index[:-1, :]
        b_idx = index[:, 1:] if axis == 1 else index[1:, :]
        step = 0.5 * ((g[:, :-1] + g[:, 1:]) if axis == 1 else (g[:-1, :] + g[1:, :]))
        la = log_gel[:, :-1] if axis == 1 else log_gel[:-1, :]
        lb = log_gel[:, 1:] if axis == 1 else log_gel[1:, :]
        use = (a_idx >= 0) | (b_idx >= 0)
        a_i, b_i, st, la_, lb_ = a_idx[use], b_idx[use], step[use], la[use], lb[use]
        e = eq + np.arange(len(st))
        r = st.copy()
        r[a_i < 0] += la_[a_i < 0]
        r[b_i < 0] -= lb_[b_i < 0]
        rows += [e[b_i >= 0], e[a_i >= 0]]
        cols += [b_i[b_i >= 0], a_i[a_i >= 0]]
        vals += [np.ones(int(np.sum(b_i >= 0))), -np.ones(int(np.sum(a_i >= 0)))]
        rhs.append(r)
        eq += len(st)
    weight = 1e-3
    rows.append(eq + np.arange(n)); cols.append(np.arange(n)); vals.append(np.full(n, weight))
    t_prior = np.exp(log_gel) - (0.0 if prior is None else block_mean(prior, k))
    rhs.append(weight * np.log(np.maximum(t_prior, 1e-3))[coarse_mask])
    A = scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(eq + n, n))
    L = scipy.sparse.linalg.spsolve((A.T @ A).tocsc(), A.T @ np.concatenate(rhs))
    coarse_log = log_gel.copy()
    coarse_log[coarse_mask] = L
    coarse_depth = np.exp(log_gel) - np.exp(coarse_log)
    full = cv2.resize(coarse_depth.astype(np.float32), (w * k, h * k), interpolation=cv2.INTER_LINEAR)
    depth[: h * k, : w * k] = full
    depth[~mask] = 0.0
    return np.maximum(depth, 0.0, out=depth)


def _reference_contact(depth, normals, top_band):
    dmax = float(depth.max())
    if not dmax > 0.0:
        return None, None
    w = np.clip(depth - dmax * (1.0 - top_band), 0.0, None).astype(np.float64)
    sel = w > 0
    if not sel.any():
        sel = depth >= dmax
        w = sel.astype(np.float64)
    w = w[sel] / w[sel].sum()
    normal = w @ normals[sel]
    return w @ contact_patch.depth_to_points(depth)[sel], normal / np.linalg.norm(normal)


def _reference_patch(image, no_contact, model):
    """The whole-image computation -> (mask, depth, point, normal, noise, normals, direct depth)."""
    diff = _reference_difference(image, no_contact)
    noise = _reference_noise(diff)
    mask = _reference_mask(contact_patch.smooth_difference(diff, model.mask_sigma), noise, model)
    if not mask.any():
        return mask, np.zeros((H, W), np.float32), None, None, noise, None, None
    normals, direct = _reference_normals(contact_patch.smooth_difference(diff, model.sigma), mask, model)
    depth = _reference_depth(normals, mask, model.grid_step, direct)
    point, normal = _reference_contact(depth, normals, model.top_band)
    return mask, depth, point, normal, noise, normals, direct


def _touches_border(mask):
    return bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


# (shape, contact point, normal, press arguments, what the mask must be like for the case to test what it says)
BOX_CASES = {
    "small, far from the border": (SPHERE, [-0.01, 0.0, 0.0], dict(depth=0.0008),
                                   lambda m, box: m.mean() < 0.15 and not _touches_border(m)),
    "in a corner, touching two borders": (SPHERE, [-0.01, 0.0, 0.0], dict(offset=(0.007, 0.009), depth=0.0015, seed=3),
                                          lambda m, box: m[0].any() and m[:, 0].any() and box[0].stop < H),
    "box clipped at the border, mask not touching it": (SPHERE, [-0.01, 0.0, 0.0],
                                                        dict(offset=(0.0, 0.008), depth=0.0015, seed=4),
                                                        lambda m, box: box[0].start == 0 and not _touches_border(m)),
    "most of the image": (BOX, [-0.03, 0.0, 0.0], dict(depth=0.0025, seed=5), lambda m, box: m.mean() > 0.9),
    "a wide band across": (sq.Superquadric(0.04, 0.04, 0.04, 1.0, 1.0), [-0.04, 0.0, 0.0], dict(depth=0.0025, seed=6),
                           lambda m, box: 0.5 < m.mean() < 0.9 and m[:, 0].any() and m[:, -1].any()),
}


@pytest.mark.parametrize("case", list(BOX_CASES))
@pytest.mark.slow
def test_image_to_patch_is_the_whole_image_computation(renderer, mesh_of, model, no_contact, case):
    shape, point, kwargs, as_described = BOX_CASES[case]
    result, *_ = press(renderer, mesh_of, shape, point, [-1.0, 0.0, 0.0], **kwargs)
    mask, depth, p, n, noise, normals, direct = _reference_patch(result.image, no_contact, model)
    box = contact_patch._work_box(mask, model.grid_step)
    assert as_described(mask, box), f"the press no longer makes the case {case!r}"
    est = contact_patch.image_to_patch(result.image, no_contact, model)
    assert est.contact
    np.testing.assert_array_equal(est.mask, mask)
    assert est.depth.dtype == depth.dtype
    np.testing.assert_allclose(est.depth, depth, rtol=0, atol=1e-9)  # metres: the solvers' rounding only
    np.testing.assert_allclose(est.point, p, rtol=0, atol=1e-9)
    np.testing.assert_allclose(est.normal, n, rtol=0, atol=1e-9)
    assert est.noise == noise
    # the public steps on their own, on the whole image: the box's results bit for bit
    diff = contact_patch.images_to_difference(result.image, no_contact)
    smooth = contact_patch.smooth_difference(diff, model.sigma)
    got_normals, got_direct = contact_patch.difference_to_normals(smooth, mask, model)
    assert np.array_equal(got_normals, normals) and np.array_equal(got_direct, direct)
    gradients = contact_patch.normals_to_log_gradients(normals)
    assert all(np.array_equal(a, b) for a, b in zip(gradients, _reference_log_gradients(normals)))
    assert np.array_equal(contact_patch.normals_to_depth(normals, mask, model.grid_step, direct), est.depth)
    got_point, got_normal = contact_patch.depth_to_contact(est.depth, normals, model.top_band)
    assert np.array_equal(got_point, est.point) and np.array_equal(got_normal, est.normal)


def test_normals_to_depth_needs_only_the_normals_near_the_mask(renderer, mesh_of, model, no_contact):
    """Normals far from the mask are never read: garbage there changes nothing; next to it, it does."""
    result, *_ = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], depth=0.0008)
    mask, _, _, _, _, normals, direct = _reference_patch(result.image, no_contact, model)
    depth = contact_patch.normals_to_depth(normals, mask, model.grid_step, direct)
    rows, cols = np.nonzero(mask)
    spoiled = normals.copy()
    far = np.ones((H, W), dtype=bool)
    far[max(rows.min() - 8, 0) : rows.max() + 9, max(cols.min() - 8, 0) : cols.max() + 9] = False
    spoiled[far] = [-0.6, 0.8, 0.0]
    assert np.array_equal(contact_patch.normals_to_depth(spoiled, mask, model.grid_step, direct), depth)
    near = spoiled.copy()
    near[rows.min() - 2, cols.min() : cols.max()] = [-0.6, 0.8, 0.0]  # the row above the mask's top
    assert not np.array_equal(contact_patch.normals_to_depth(near, mask, model.grid_step, direct), depth)


def test_noise_from_a_histogram_and_the_saturation_count_are_the_plain_computation(renderer, mesh_of, no_contact):
    result, *_ = press(renderer, mesh_of, BOX, [-0.03, 0.0, 0.0], [-1.0, 0.0, 0.0], seed=2)
    rng = np.random.default_rng(0)
    pairs = [(result.image, no_contact), (no_contact, no_contact), (renderer.no_contact(seed=5), no_contact)]
    for _ in range(3):  # every level, saturated ends included
        pairs.append(tuple(rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)))
    for image, background in pairs:
        diff = contact_patch.images_to_difference(image, background)
        assert np.array_equal(diff, _reference_difference(image, background))
        noise = _reference_noise(diff)
        assert contact_patch._whole_level_noise(diff) == noise == contact_patch.difference_to_noise(diff)
        odd = diff[:-1, :-1, :1]  # an odd number of residuals: the median is one of them
        assert odd[1:-1, 1:-1].size % 2 == 1 and contact_patch._whole_level_noise(odd) == _reference_noise(odd)
    for _ in range(300):  # few residuals, spread out: the two middle ones usually differ
        shape = (rng.integers(3, 7), rng.integers(3, 7), rng.integers(1, 4))
        diff = rng.integers(-255, 256, shape).astype(np.float32)
        assert contact_patch._whole_level_noise(diff) == _reference_noise(diff)
    image = no_contact.copy()
    for fraction, raises in ((0.6, True), (0.4, False)):  # pixels clipped in one channel only
        rows = int(fraction * H)
        image[:rows, :, 1] = np.where(no_contact[:rows, :, 1] == 255, 0, 255)
        if raises:
            with pytest.raises(InputError, match="saturated"):
                contact_patch.images_to_difference(image, no_contact)
        else:
            image[rows:] = no_contact[rows:]
            expected = _reference_difference(image, no_contact)
            assert np.array_equal(contact_patch.images_to_difference(image, no_contact), expected)


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_regression_features_and_normals_are_the_textbook_evaluation(degree):
    rng = np.random.default_rng(degree)
    n = 5000  # more than one chunk
    colour = (rng.standard_normal((n, 3)) * np.exp(rng.uniform(-8, 8, (n, 3)))).astype(np.float32)
    colour[:10] = 0.0
    rays = np.concatenate([np.ones((n, 1)), rng.uniform(-0.6, 0.6, (n, 2))], axis=1)
    got = contact_patch.regression_features(colour, rays, degree, 64.0)
    assert got.flags.c_contiguous and np.array_equal(got, _reference_features(colour, rays, degree, 64.0))
    assert contact_patch.regression_features(colour[:0], rays[:0], degree, 64.0).shape == (0, got.shape[1])
    # the model evaluated chunk by chunk: the whole matrix's product, up to the rounding of its sums
    coefficients = rng.standard_normal((got.shape[1], 3))
    pred = contact_patch.regression_predict(colour, rays, degree, 64.0, coefficients)
    assert pred.shape == (n, 3)
    assert np.all(np.abs(pred - got @ coefficients) <= 1e-12 * (np.abs(got) @ np.abs(coefficients)))
    assert contact_patch.regression_predict(colour[:0], rays[:0], degree, 64.0, coefficients).shape == (0, 3)
    lateral = rng.standard_normal((n, 2)) * rng.uniform(0.0, 1.5, (n, 1))
    lateral[:5] = [[0.0, 0.0], [1.0, 0.0], [0.0, -2.0], [np.sin(np.deg2rad(65.0)), 0.0], [1e-300, -1e-300]]
    assert np.array_equal(contact_patch.lateral_to_normals(lateral), _reference_lateral_to_normals(lateral))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_depth_integration_solve_is_the_least_squares_solution(seed):
    """The banded Cholesky solve of the normal equations against a dense least-squares solve of the system
    itself, on a blob of cells of a small grid (some touching its border, so some equations have one end
    outside the mask and some none), with random right-hand sides."""
    rng = np.random.default_rng(seed)
    h, w = 9, 12
    yy, xx = np.mgrid[:h, :w]
    inside = (yy - rng.uniform(2, 6)) ** 2 / 9 + (xx - rng.uniform(2, 9)) ** 2 / 16 < rng.uniform(0.6, 1.5)
    index = -np.ones((h, w), dtype=np.int64)
    index[inside] = np.arange(int(inside.sum()))
    n = int(inside.sum())
    ends = np.concatenate([np.stack([index[:, :-1].ravel(), index[:, 1:].ravel()], axis=1),
                           np.stack([index[:-1, :].ravel(), index[1:, :].ravel()], axis=1)])
    ends = ends[(ends >= 0).any(axis=1)]
    rhs, prior_log = rng.standard_normal(len(ends)), rng.standard_normal(n)
    weight = contact_patch._PRIOR_WEIGHT
    A = np.zeros((len(ends) + n, n))
    for e, (a, b) in enumerate(ends):
        if a >= 0:
            A[e, a] = -1.0
        if b >= 0:
            A[e, b] = 1.0
    A[len(ends):] = weight * np.eye(n)
    expected = np.linalg.lstsq(A, np.concatenate([rhs, weight * prior_log]), rcond=None)[0]
    got = contact_patch._solve_normal_equations(ends, rhs, prior_log)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def test_magnitude_adds_the_channels_as_numpy_did():
    rng = np.random.default_rng(1)
    smooth = (rng.standard_normal((H, W, 3)) * np.exp(rng.uniform(-10, 10, (H, W, 3)))).astype(np.float32)
    assert np.array_equal(contact_patch._magnitude(smooth), np.sqrt(np.sum(smooth.astype(np.float64) ** 2, axis=-1)))
