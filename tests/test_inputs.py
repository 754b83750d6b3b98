"""Checks of plausibly wrong inputs (tactile6d.perception.inputs): grey and BGR images, no-contact images, pose lines
whose axis is not a unit vector, sensors whose bodies overlap, one sensor only."""

import glob
import warnings

import numpy as np
import pytest
import trimesh

from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.core.geometry import is_rotation, make_pose, random_rotations, rotation_angle, text_to_poses
from tactile6d.core.settings import SensorSettings
from tactile6d.core.sensor import BOX_CENTER, BOX_HALF_EXTENTS, bodies_overlap, contact_points, sensor_poses_touching
from tactile6d.data.hdf5 import read_scene_dir, read_tactile_image
from tactile6d.perception import inputs
from tactile6d.perception.encode import load_background


def triplet_folders(data_dir):
    return sorted({p.rsplit("/", 1)[0] for p in glob.glob(str(data_dir / "caddeo2023/triplets/*/*/poses_sensors.txt"))})


@pytest.fixture(scope="module")
def default_background(data_dir):
    return load_background(compose_config(), data_dir)


# --- grey and BGR images ------------------------------------------------------------------------------


@pytest.mark.slow
def test_no_image_of_the_papers_triplets_looks_bgr_and_every_swapped_one_does(data_dir, default_background):
    files = sorted(glob.glob(str(data_dir / "caddeo2023/triplets/*/*/Image_heatmap_*.png")))
    assert len(files) == 120
    for path in files:
        image = read_tactile_image(path)
        assert not inputs.looks_like_bgr(image, default_background), path
        assert inputs.looks_like_bgr(np.ascontiguousarray(image[..., ::-1]), default_background), path
        assert not inputs.is_grey(image)


def test_no_rendered_image_looks_bgr_and_every_swapped_one_does(default_background):
    """A sphere pressed 0.5-2.5 mm at several rolls, rendered over the default background."""
    from tactile6d.sim.render import DigitRenderer

    renderer = DigitRenderer.from_default_config(np.ascontiguousarray(default_background[..., ::-1]))
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    normals = np.array([[0, 0, -1.0], [1, 0, 0], [0, 1, 0], [0.6, 0, 0.8], [0, -0.6, -0.8]])
    depths = np.linspace(0.0005, 0.0025, len(normals))
    T = sensor_poses_touching(0.02 * normals, normals, np.arange(len(normals)), depths)
    for i, pose in enumerate(T):
        image = renderer.render(sphere, np.eye(4), pose, seed=i).image
        assert (image != renderer.no_contact(seed=i)).any()  # a contact was rendered
        assert not inputs.looks_like_bgr(image, default_background)
        assert inputs.looks_like_bgr(np.ascontiguousarray(image[..., ::-1]), default_background)


def test_grey_and_bgr_images_are_named(default_background):
    images = np.stack([default_background] * 3)
    backgrounds = np.broadcast_to(default_background, images.shape)
    inputs.check_images_against_backgrounds(images, backgrounds)  # as given: fine
    grey = images.copy()
    grey[1] = default_background.mean(axis=-1, keepdims=True).astype(np.uint8)
    with pytest.raises(InputError, match="image 1 is grey .* a DIGIT image is RGB colour"):
        inputs.check_images_against_backgrounds(grey, backgrounds)
    bgr = images.copy()
    bgr[2] = default_background[..., ::-1]
    with pytest.raises(InputError, match="image 2 looks like BGR: .*read_tactile_image or convert with cv2.cvtColor"):
        inputs.check_images_against_backgrounds(bgr, backgrounds)


def test_the_grey_image_error_names_a_reader_that_exists(default_background):
    from tactile6d.data import hdf5

    grey = np.repeat(default_background.mean(axis=-1, keepdims=True).astype(np.uint8), 3, axis=-1)
    for check in (lambda: inputs.check_backgrounds(grey),
                  lambda: inputs.check_images_against_backgrounds(grey[None], default_background[None])):
        with pytest.raises(InputError, match=r"read it in colour \(tactile6d\.data\.hdf5\.read_tactile_image") as info:
            check()
        assert "tactile6d.io" not in str(info.value)
    assert callable(hdf5.read_tactile_image)


def test_images_of_another_dtype_are_refused_with_how_to_convert_them(default_background):
    as_float = default_background.astype(np.float32) / 255
    with pytest.raises(InputError, match=r"image 0 has dtype float32, tactile images must be uint8 \(0-255\) .*"
                                         r"\(image \* 255\)\.round\(\)\.astype\(np\.uint8\)"):
        inputs.check_images([as_float], 1)
    with pytest.raises(InputError, match=r"image 1 has dtype uint16, .*\(image >> 8\)\.astype\(np\.uint8\)"):
        inputs.check_images([default_background, default_background.astype(np.uint16) << 8], 2)
    with pytest.raises(InputError, match=r"background has dtype float64, .*\(image \* 255\)"):
        inputs.check_backgrounds(default_background / 255.0)
    with pytest.raises(InputError, match=r"image 0 has dtype int64, tactile images must be uint8 \(0-255\) as the "
                                         r"camera gives them$"):
        inputs.check_images([default_background.astype(np.int64)], 1)


def test_one_sensors_image_may_be_given_alone_as_its_pose_may(default_background):
    np.testing.assert_array_equal(inputs.check_images(default_background, 1), default_background[None])
    with pytest.raises(InputError, match=r"tactile images must be \(L, 320, 240, 3\), got shape \(320, 240, 3\)"):
        inputs.check_images(default_background, 2)


def test_a_raw_camera_frame_is_named_as_one_everywhere_an_image_is_read(tmp_path, default_background):
    """The camera's raw frame (240 rows x 320 columns) is ``np.rot90`` of what digit-interface returns: images,
    no-contact images, image files and the contact patch all name the turn; other sizes get the plain error."""
    import cv2

    from tactile6d.perception import contact_patch

    raw = np.ascontiguousarray(np.rot90(default_background, -1))
    assert raw.shape == (240, 320, 3) and (np.rot90(raw) == default_background).all()
    turned = r"320 wide x 240 high, a DIGIT image is 240 wide x 320 high .*rotated by 90 degrees.*np\.rot90\(frame\)"
    with pytest.raises(InputError, match="image 1 is " + turned):
        inputs.check_images([default_background, raw], 2)
    with pytest.raises(InputError, match="background 0 is " + turned + r".*one per sensor"):
        inputs.check_backgrounds(np.stack([raw, raw]))
    cv2.imwrite(str(tmp_path / "raw.png"), raw)
    with pytest.raises(InputError, match="raw.png is " + turned):
        read_tactile_image(tmp_path / "raw.png")
    with pytest.raises(InputError, match="no_contact is " + turned):
        contact_patch.check_image(raw, "no_contact")
    with pytest.raises(InputError, match=r"image 0 is 240 wide x 320 high.*it has 4 channels"):
        inputs.check_images([np.zeros((320, 240, 4), np.uint8)], 1)
    with pytest.raises(InputError, match=r"image 0 is 120 wide x 150 high, a DIGIT image is 240 wide x 320 high "
                                         r"\(array shape \(320, 240, 3\)\); an image of its proportions at another "
                                         r"size .* is read resized$"):
        inputs.check_images([np.zeros((150, 120, 3), np.uint8)], 1)


def test_a_background_whose_red_and_blue_agree_never_calls_an_image_bgr():
    """With R = B in the no-contact image, the swap changes nothing: no evidence, no error."""
    rng = np.random.default_rng(0)
    background = rng.integers(40, 200, (320, 240, 3)).astype(np.uint8)
    background[..., 2] = background[..., 0]
    image = np.clip(background.astype(int) + rng.integers(-3, 4, background.shape), 0, 255).astype(np.uint8)
    assert not inputs.looks_like_bgr(image, background)
    assert not inputs.looks_like_bgr(image[..., ::-1], background)


# --- pose lines -------------------------------------------------------------------------------------------


def test_a_rotation_axis_that_is_not_unit_length_names_the_line():
    text = "0 0 0 1 0 0 0.5\n\n0 0 0 0 0.5 0 1.0\n"
    with pytest.raises(ValueError, match=r"line 3: rotation axis of length 0.5, not a unit vector"):
        text_to_poses(text)
    text_to_poses("0 0 0 0 1.0009 0 1.0\n")  # within 1e-3: rounding in someone's file
    with pytest.raises(ValueError, match="line 1: zero rotation axis with a non-zero angle"):
        text_to_poses("0 0 0 0 0 0 1.0\n")


def test_an_angle_in_degrees_is_named_and_any_angle_in_radians_passes():
    with pytest.raises(ValueError, match=r"line 2: rotation angle 179.8 is more than a full turn \(2 pi\): the "
                                         r"format's angle is in radians \(179.8 deg would be 3.1381\)"):
        text_to_poses("0 0 0 1 0 0 0.5\n0 0 0 0 1 0 179.8\n")
    with pytest.raises(ValueError, match="rotation angle -90 is more than a full turn"):
        text_to_poses("0 0 0 0 0 1 -90\n")
    turns = text_to_poses("0 0 0 0 0 1 6.2831853\n0 0 0 0 0 1 -6.2831853\n0 0 0 0 0 1 4.19\n")
    np.testing.assert_allclose(turns[0], np.eye(4), atol=1e-6)  # a full turn, in radians, is accepted
    np.testing.assert_allclose(turns[1], np.eye(4), atol=1e-6)


def test_a_rounded_rotation_is_taken_for_the_nearest_rotation_and_a_wrong_one_refused():
    T = make_pose(random_rotations(1, np.random.default_rng(3))[0], [0.1, 0.0, 0.2])
    rounded = np.round(T, 4)  # a calibration file with 4 decimals: R^T R about 1e-4 off the identity
    assert not is_rotation(rounded[:3, :3], atol=inputs.EXACT_ROTATION)
    given = rounded.copy()
    checked = inputs.check_sensor_poses(given)
    np.testing.assert_array_equal(given, rounded)  # the caller's array is left as it was
    assert is_rotation(checked[0, :3, :3], atol=1e-12)
    assert rotation_angle(checked[0, :3, :3], T[:3, :3]) < 1e-3
    np.testing.assert_array_equal(inputs.check_sensor_poses(T)[0], T)  # an exact rotation is kept bit for bit
    scaled = T.copy()
    scaled[:3, :3] *= 1.01
    with pytest.raises(InputError, match=r"sensor pose 0: the upper-left 3x3 block is not a rotation matrix "
                                         r"\(R\^T R is 0.02 off the identity"):
        inputs.check_sensor_poses(scaled)


def test_every_poses_file_of_the_papers_triplets_passes(data_dir):
    folders = triplet_folders(data_dir)
    assert len(folders) == 40
    for folder in folders:
        T, _ = read_scene_dir(folder)
        inputs.check_bodies_apart(T)


# --- sensors whose bodies overlap -------------------------------------------------------------------------


def random_pose_pairs(n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield (make_pose(random_rotations(1, rng)[0], rng.uniform(-0.04, 0.04, 3)),
               make_pose(random_rotations(1, rng)[0], rng.uniform(-0.04, 0.04, 3)))


def sampled_overlap(T_a, T_b, n=20000, seed=0) -> bool:
    """The naive reference: some of n points drawn in a's body box lie in b's."""
    local = np.random.default_rng(seed).uniform(-1, 1, (n, 3)) * BOX_HALF_EXTENTS + BOX_CENTER
    world = local @ T_a[:3, :3].T + T_a[:3, 3]
    in_b = (world - T_b[:3, 3]) @ T_b[:3, :3]
    return bool(np.any(np.all(np.abs(in_b - BOX_CENTER) < BOX_HALF_EXTENTS, axis=1)))


def overlap_found(T, margin=0.0) -> bool:
    try:
        inputs.check_bodies_apart(T, margin)
    except InputError:
        return True
    return False


@pytest.mark.slow
def test_the_overlap_check_agrees_with_the_scene_generators_and_with_sampling():
    """The check (its bounding-sphere shortcut included) finds what the separating-axis test the scene
    generator places sensors with finds; sampling never finds an overlap the check misses."""
    agree = 0
    for k, (T_a, T_b) in enumerate(random_pose_pairs(200, seed=1)):
        found = overlap_found(np.stack([T_a, T_b]))
        assert found == bodies_overlap(T_a, T_b)
        sampled = sampled_overlap(T_a, T_b, seed=k) or sampled_overlap(T_b, T_a, seed=k)
        if sampled:
            assert found
        agree += found == sampled
    assert agree >= 190  # sampling misses a few grazing overlaps


def test_overlapping_sensors_are_named_and_side_by_side_ones_pass():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, 1, 3] = 2 * BOX_HALF_EXTENTS[1] + 1e-4  # beside sensor 0, 0.1 mm apart
    T[2, 1, 3] = -2 * BOX_HALF_EXTENTS[1] + 3e-4  # 0.3 mm into sensor 0: within the margin
    inputs.check_bodies_apart(T)
    T[2, 1, 3] = -2 * BOX_HALF_EXTENTS[1] + 2e-3  # 2 mm into sensor 0
    with pytest.raises(InputError, match="sensors 0 and 2 overlap"):
        inputs.check_bodies_apart(T)


def test_the_overlap_margin_follows_the_sensor_pose_error():
    """Exact poses keep the 0.5 mm margin; poses off by sigma per axis (the default, 1.5 mm and 1.5 deg) let two
    bodies overlap by up to 2 sqrt(2) contact sigma (each shrunk by half of it), and no farther."""
    default = SensorSettings.from_cfg(compose_config().sensors)
    assert inputs.body_overlap_margin(0.0) == inputs.BODY_OVERLAP_MARGIN
    margin = inputs.body_overlap_margin(default.pair_distance_tolerance)
    assert margin == pytest.approx(np.sqrt(2) * default.contact_sigma) and 2.3e-3 < margin < 2.4e-3
    T = np.tile(np.eye(4), (2, 1, 1))
    for overlap, refused in ((2 * margin - 1e-4, False), (2 * margin + 1e-4, True)):
        T[1, 1, 3] = 2 * BOX_HALF_EXTENTS[1] - overlap
        assert overlap_found(T, margin) == refused
        assert overlap_found(T, inputs.BODY_OVERLAP_MARGIN)  # either is refused with exact poses


def test_one_sensor_warns_that_the_pose_is_under_determined():
    with pytest.warns(inputs.UnderdeterminedPoseWarning, match="under-determined"):
        inputs.warn_if_underdetermined(1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        inputs.warn_if_underdetermined(2)


# --- no-contact images ------------------------------------------------------------------------------------


def test_backgrounds_one_for_all_or_one_per_sensor(default_background):
    one = inputs.check_backgrounds(default_background)
    assert one.shape == (320, 240, 3)
    per_sensor = inputs.backgrounds_per_sensor(one, 3)
    assert per_sensor.shape == (3, 320, 240, 3) and not per_sensor.flags.writeable  # a view, no copy
    three = inputs.check_backgrounds([default_background] * 3)
    assert inputs.backgrounds_per_sensor(three, 3).shape == (3, 320, 240, 3)
    with pytest.raises(InputError, match="3 background images for 2 sensors"):
        inputs.backgrounds_per_sensor(three, 2)
    with pytest.raises(InputError, match="no background image given"):
        inputs.check_backgrounds([])


def test_the_checks_are_cheap(default_background):
    """Once per estimate: well under a millisecond per sensor (measured 0.3 ms an image on 2 cores)."""
    import time

    images = np.stack([default_background] * 3)
    backgrounds = inputs.backgrounds_per_sensor(default_background, 3)
    T = sensor_poses_touching(np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0]]), np.array([[0, 0, 1.0]] * 3))
    t0 = time.perf_counter()
    for _ in range(20):
        inputs.check_images_against_backgrounds(images, backgrounds)
        inputs.check_bodies_apart(T)
    assert (time.perf_counter() - t0) / 20 < 0.02


# --- sensors out of the object's reach, and a best pose that presses into a sensor ----------------------------


def test_sensors_too_far_apart_for_the_object_are_named_with_the_units_hint():
    T = sensor_poses_touching(np.array([[0.05, 0, 0], [-0.05, 0, 0], [0, 0.05, 0]]),
                              np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0]]), [0.0, 0.0, 0.0])
    touching = np.ones(3, dtype=bool)
    inputs.check_sensors_within_reach(T, touching, object_extent=0.12, pose_tolerance=0.0045)  # a 10 cm object
    in_mm = T.copy()
    in_mm[:, :3, 3] *= 1000.0
    with pytest.raises(InputError, match=r"sensors 0 and 1 both touch, but their contacts are 140 m apart and the "
                                         r"object spans at most 0.12 m: .*these look like millimetres"):
        inputs.check_sensors_within_reach(in_mm, touching, 0.12, 0.0045)
    far = T.copy()
    far[2, :3, 3] += [0.0, 500.0, 0.0]  # 500 m off: not even millimetres
    with pytest.raises(InputError, match=r"sensors 0 and 2 .* no pose can touch both; check the sensor poses"):
        inputs.check_sensors_within_reach(far, touching, 0.12, 0.0045)
    inputs.check_sensors_within_reach(far, np.array([True, True, False]), 0.12, 0.0045)  # a lifted finger
    # Out of this object's reach but within a hand's span: not an input error (the selection finds no match,
    # and identification goes on to the next object).
    near = T.copy()
    near[2, :3, 3] += [0.0, 0.5, 0.0]
    inputs.check_sensors_within_reach(near, touching, 0.12, 0.0045)
    # Beyond a hand's span, the bound is the object's extent, both gels' reach, the tolerance and the margin.
    pair = in_mm[:2].copy()
    gap = float(np.linalg.norm(np.diff(contact_points(pair), axis=0)))
    extent = gap - 2 * inputs.GEL_REACH - 0.0045 - inputs.REACH_MARGIN
    inputs.check_sensors_within_reach(pair, touching[:2], extent + 1e-6, 0.0045)
    with pytest.raises(InputError):
        inputs.check_sensors_within_reach(pair, touching[:2], extent - 1e-6, 0.0045)


def test_a_best_pose_that_presses_deep_into_a_sensor_is_warned_about():
    allowance = SensorSettings(1.5, 1.5).contact_sigma
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        inputs.warn_if_pressed_in(np.array([0.0, 0.002, np.nan]), allowance)
        inputs.warn_if_pressed_in(np.array([allowance + inputs.PENETRATION_WARNING, 0.0, 0.0]), allowance)
        inputs.warn_if_pressed_in(np.zeros(0), allowance)
    with pytest.warns(inputs.PenetrationWarning, match=r"the best pose presses 9\.6 mm into sensor 2's body, 7\.9 mm "
                                                       r"more than .* T_world_sensor \(the sensor's frame in the world, "
                                                       r"not its inverse\)"):
        inputs.warn_if_pressed_in(np.array([0.0057, 0.0053, 0.0096]), allowance)
    # Where images were read against another unit's no-contact image, their contacts are the likelier fault.
    with pytest.warns(inputs.PenetrationWarning, match=r"Image 2 was read against another unit's no-contact "
                                                       r"image .* the contacts read from it") as caught:
        inputs.warn_if_pressed_in(np.array([0.0057, 0.0053, 0.0096]), allowance, misread=(2,))
    assert "T_world_sensor" not in str(caught[0].message)
    with pytest.warns(inputs.PenetrationWarning, match=r"Images 0, 2 were read against .* read from them"):
        inputs.warn_if_pressed_in(np.array([0.0057, 0.0053, 0.0096]), allowance, misread=(0, 2))


def test_images_and_backgrounds_at_another_size_are_resized_one_warning_each(default_background):
    """Images at 120 x 160 (TACTO's default size) come out at 240 x 320, each named; a (L, 320, 240, 3) array of
    backgrounds is returned as it is (no copy), a list at another size stacked resized; dtype is checked first."""
    from tactile6d.data.hdf5 import ImageSizeWarning

    small = default_background[::2, ::2]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        images = inputs.check_images([default_background, small], 2)
        backgrounds = inputs.check_backgrounds([small, default_background])
    assert images.shape == backgrounds.shape == (2, 320, 240, 3)
    np.testing.assert_array_equal(images[0], default_background)
    np.testing.assert_array_equal(images[1], backgrounds[0])
    assert [(w.category, w.message.name) for w in caught] == [(ImageSizeWarning, "image 1"),
                                                              (ImageSizeWarning, "background 0")]
    stacked = np.stack([default_background] * 3)
    assert inputs.check_backgrounds(stacked) is stacked
    with pytest.raises(InputError, match="image 0 has dtype float32"):
        inputs.check_images([small.astype(np.float32)], 1)
    with pytest.raises(InputError, match="background is grey"), warnings.catch_warnings():
        warnings.simplefilter("ignore", ImageSizeWarning)
        inputs.check_backgrounds(np.repeat(small[..., :1], 3, axis=2))
