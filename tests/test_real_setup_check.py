"""scripts/real_setup_check.py: what each condition changes in a scene set, and the figures of a condition."""

from dataclasses import replace

import numpy as np
import pytest
from script_loader import load_script

from tactile6d.core import geometry as g
from tactile6d.sim import scenes

check = load_script("real_setup_check")
compare = load_script("compare_errors")


def small_set(n=3, L=3) -> scenes.SceneSet:
    rng = np.random.default_rng(0)
    T_sensors = np.broadcast_to(g.make_pose(np.eye(3), [0.1, 0.0, 0.2]), (n, L, 4, 4)).copy()
    return scenes.SceneSet(names=np.array([f"s{i}" for i in range(n)]), objects=np.array(["a", "a", "b"][:n]),
                           T_world_object=np.broadcast_to(np.eye(4), (n, 4, 4)).copy(), T_world_sensors=T_sensors,
                           images=rng.integers(40, 200, (n, L, 320, 240, 3), dtype=np.uint8),
                           contact_points=np.zeros((n, L, 3)), contact_normals=np.zeros((n, L, 3)),
                           contact_types=np.zeros((n, L), dtype=np.int64))


BACKGROUND = np.full((320, 240, 3), 120, np.uint8)


def test_clean_is_the_set_itself():
    s = small_set()
    assert check.real_set_up(s, "clean", BACKGROUND, np.random.default_rng(0)) is s


def test_noise_changes_the_images_by_about_its_sigma_and_nothing_else():
    s = small_set()
    out = check.real_set_up(s, "noise", BACKGROUND, np.random.default_rng(0))
    diff = out.images.astype(float) - s.images
    assert diff.std() == pytest.approx(check.NOISE_STD, rel=0.05)
    np.testing.assert_array_equal(out.T_world_sensors, s.T_world_sensors)
    assert out.backgrounds is None


def test_light_drifts_each_sensor_and_keeps_the_old_no_contact_image():
    s = small_set()
    out = check.real_set_up(s, "light", BACKGROUND, np.random.default_rng(0))
    gains, gammas = out.extra["light_gain"], out.extra["light_gamma"]
    assert gains.shape == (3, 3, 3) and np.all(np.abs(gains - 1) <= check.GAIN_MAX)
    assert np.all((gammas >= check.GAMMA_RANGE[0]) & (gammas <= check.GAMMA_RANGE[1]))
    assert not out.extra["background_rerecorded"].any()  # the unit's no-contact image is the one of before
    np.testing.assert_array_equal(out.backgrounds, np.broadcast_to(BACKGROUND, out.backgrounds.shape))
    assert np.abs(out.images.astype(float) - s.images).mean() > 3  # a drift, not only the noise
    np.testing.assert_array_equal(out.T_world_object, s.T_world_object)


def test_slight_drifts_each_sensor_by_a_few_percent_of_gain_and_no_gamma():
    s = small_set()
    out = check.real_set_up(s, "slight", BACKGROUND, np.random.default_rng(0))
    gains = out.extra["light_gain"]
    assert np.all(np.abs(gains - 1) <= check.SLIGHT_GAIN_MAX) and np.abs(gains - 1).max() > 0.01
    np.testing.assert_array_equal(out.extra["light_gamma"], np.ones_like(gains))
    np.testing.assert_array_equal(out.backgrounds, np.broadcast_to(BACKGROUND, out.backgrounds.shape))
    assert 1.0 < np.abs(out.images.astype(float) - s.images).mean() < 4.0  # a grey level or two, and the noise


@pytest.mark.parametrize("condition, levels", [("recorded+1", 1), ("recorded-1", -1)])
def test_recorded_gives_every_sensor_the_no_contact_image_a_grey_level_off_and_nothing_else(condition, levels):
    s = small_set()
    out = check.real_set_up(s, condition, BACKGROUND, np.random.default_rng(0))
    assert out.backgrounds.shape == s.images.shape
    assert set(np.unique(out.backgrounds.astype(int) - BACKGROUND)) == {levels}
    assert out.images is s.images and out.T_world_sensors is s.T_world_sensors


@pytest.mark.parametrize("condition", ["other-unit", "other-unit-own"])
def test_other_unit_moves_each_press_onto_the_other_units_no_contact_image(condition):
    s = small_set()
    other = np.full((320, 240, 3), 90, np.uint8)
    other[:10] = 250  # where a press onto it saturates
    out = check.real_set_up(s, condition, BACKGROUND, np.random.default_rng(0), other)
    expected = np.clip(s.images.astype(int) - BACKGROUND + other, 0, 255)
    np.testing.assert_array_equal(out.images, expected)
    assert out.images[..., :10, :, :].max() == 255
    if condition == "other-unit":
        assert out.backgrounds is None  # nothing passed: the estimator's default
    else:
        np.testing.assert_array_equal(out.backgrounds, np.broadcast_to(other, s.images.shape))
    assert out.T_world_sensors is s.T_world_sensors


def test_the_drawer_is_each_unit_turned_and_mirrored_either_way():
    a = np.random.default_rng(1).integers(0, 256, (320, 240, 3), dtype=np.uint8)
    drawer = check.drawer_units({"a": a, "b": a // 2})
    assert list(drawer) == ["a turned", "a mirrored", "a flipped", "b turned", "b mirrored", "b flipped"]
    np.testing.assert_array_equal(drawer["a turned"], a[::-1, ::-1])
    np.testing.assert_array_equal(drawer["a mirrored"], a[:, ::-1])
    np.testing.assert_array_equal(drawer["b flipped"], (a // 2)[::-1])


@pytest.mark.parametrize("condition", check.DRAWER_CONDITIONS)
def test_drawer_moves_each_sensor_onto_its_own_unit_of_the_drawer(condition):
    s = small_set()
    drawer = {f"u{k}": np.full((320, 240, 3), 60 + 20 * k, np.uint8) for k in range(6)}
    out = check.real_set_up(s, condition, BACKGROUND, np.random.default_rng(3), drawer=drawer)
    drawn = out.extra["unit"]
    assert drawn.shape == (3, 3) and all(len(set(row)) == 3 for row in drawn)  # three distinct units a scene
    units = np.stack(list(drawer.values()))[drawn]
    np.testing.assert_array_equal(out.images, np.clip(s.images.astype(int) - BACKGROUND + units, 0, 255))
    if condition == "drawer-own":
        np.testing.assert_array_equal(out.backgrounds, units)
    else:
        assert out.backgrounds is None  # nothing passed: the default, and the known units when given
    again = check.real_set_up(s, "drawer", BACKGROUND, np.random.default_rng(3), drawer=drawer)
    np.testing.assert_array_equal(again.extra["unit"], drawn)  # the same rng draws the same units


def test_kinematic_moves_the_sensor_poses_by_the_declared_sigmas_and_keeps_the_images():
    s = small_set(n=3, L=3)
    out = check.real_set_up(s, "kinematic", BACKGROUND, np.random.default_rng(0))
    np.testing.assert_array_equal(out.images, s.images)
    moved = np.linalg.inv(s.T_world_sensors) @ out.T_world_sensors  # the error, in each sensor's frame
    np.testing.assert_allclose(moved[..., :3, 3], out.extra["pose_error_translation"], atol=1e-12)
    assert 0 < np.abs(out.extra["pose_error_translation"]).max() < 6 * 1e-3 * check.SIGMA_MM


def test_jpeg_and_blur_pass_images_and_no_contact_images_through_the_same_camera():
    """A camera's stream: every image and each sensor's no-contact image compressed (or blurred) alike, so that
    an untouched image still equals its no-contact image; the poses stay."""
    s = small_set()
    s = replace(s, images=np.stack([np.stack([BACKGROUND] * 3)] * 3))  # nothing touches
    for condition in ("jpeg", "jpeg60", "jpeg90", "blur"):
        out = check.real_set_up(s, condition, BACKGROUND, np.random.default_rng(0))
        assert out.backgrounds.shape == s.images.shape
        np.testing.assert_array_equal(out.images, out.backgrounds)
        np.testing.assert_array_equal(out.T_world_sensors, s.T_world_sensors)


def test_the_camera_conditions_change_a_textured_image_as_their_strength():
    rng = np.random.default_rng(1)
    image = np.clip(rng.normal(120, 30, (320, 240, 3)), 0, 255).astype(np.uint8)
    s = small_set(n=1, L=1)
    s = replace(s, images=image[None, None])
    error = {c: np.abs(check.real_set_up(s, c, BACKGROUND, rng).images[0, 0].astype(float) - image).mean()
             for c in ("jpeg", "jpeg60", "blur")}
    assert 0 < error["jpeg"] < error["jpeg60"]  # more compression, more loss
    blurred = check.real_set_up(s, "blur", BACKGROUND, rng).images[0, 0].astype(float)
    assert blurred.std() < 0.5 * image.std()  # noise averaged out over the kernel


def test_an_unknown_condition_is_refused():
    with pytest.raises(ValueError, match="choose from"):
        check.real_set_up(small_set(), "fog", BACKGROUND, np.random.default_rng(0))


def test_the_row_of_a_condition_against_a_naive_count():
    # 4 scenes of 2 objects, 2 ranked poses each (m): the best pose's error and ADI in column 0.
    position = np.array([[0.004, 0.1], [0.03, 0.1], [0.01, 0.1], [np.nan, np.nan]])
    adi = np.array([[0.002, 0.05], [0.025, 0.05], [0.019, 0.05], [np.nan, np.nan]])
    errors = {"position": position, "adi": adi, "adi_rotation": adi, "contact_ok": np.ones((4, 2), bool)}
    row = check.summary_row(errors, np.array(["a", "a", "b", "b"]))
    assert row["pos_err_cm_mean"] == pytest.approx(100 * np.mean([0.004, 0.03, 0.01]), abs=0.005)
    assert row["pos_err_cm_median"] == pytest.approx(1.0)
    assert row["adi_within_2cm_pct"] == pytest.approx(50.0)  # 2 of 4: a failed scene is not within


def test_the_drift_drawn_is_read_back_and_a_clean_set_has_none():
    s = small_set()
    drifted = check.real_set_up(s, "light", BACKGROUND, np.random.default_rng(0))
    gain, gamma = check.drift_drawn(drifted, 1)
    np.testing.assert_array_equal(gain, drifted.extra["light_gain"][1])
    np.testing.assert_array_equal(gamma, drifted.extra["light_gamma"][1])
    np.testing.assert_array_equal(check.drift_drawn(s, 1)[0], np.ones((3, 3)))


def test_the_light_fits_row_against_a_naive_count():
    from tactile6d.perception.photometric import LightFit

    def fit(gain, gamma, outliers, applied):  # the LightFit whose gain and gamma are these
        exponent = 1.0 / np.asarray(gamma, float)
        return LightFit(-np.log(gain) * exponent, exponent, np.zeros(3), outliers, applied)

    fits = [fit([1.0, 1.1, 1.0], [1.0, 1.0, 1.0], 0.2, True), fit([1.0, 1.0, 1.0], [1.2, 1.0, 1.0], 0.4, False)]
    row = check.light_fit_row(fits, np.ones((2, 3)), np.ones((2, 3)))
    assert row["gain_err_median"] == pytest.approx(0.05, abs=1e-4)  # 0.1 and 0.0
    assert row["gamma_err_p90"] == pytest.approx(0.18, abs=1e-4)  # 0.0 and 0.2
    assert row["outliers_mean"] == pytest.approx(0.3) and row["applied"] == 1 and row["images"] == 2


def test_the_per_scene_errors_written_are_what_compare_errors_pairs(tmp_path):
    position = np.array([[0.004, 0.1], [0.03, 0.1], [np.nan, np.nan]])
    errors = {"position": position, "adi": position, "adi_rotation": position, "contact_ok": np.ones((3, 2), bool)}
    check.write_errors(str(tmp_path / "base-light.npz"), np.array(["a", "a", "b"]), errors)
    np.testing.assert_array_equal(compare.best_position_cm(str(tmp_path / "base-light.npz")), [0.4, 3.0, np.nan])
    with np.load(tmp_path / "base-light.npz") as data:
        assert data["objects"].tolist() == ["a", "a", "b"]


def test_shade_image_is_a_ramp_of_gain_per_channel_against_a_loop():
    """1 at the centre, 1 + slope where the direction meets the edge, 1 - slope opposite; each channel its own."""
    rng = np.random.default_rng(3)
    image = rng.integers(50, 200, (16, 12, 3), dtype=np.uint8)
    slopes, angles = np.array([0.05, 0.1, 0.08]), np.array([0.0, np.pi / 2, 2.5])
    out = check.shade_image(image, slopes, angles)
    expected = np.empty(image.shape, dtype=np.uint8)
    for r in range(16):
        for col in range(12):
            v, u = (r + 0.5) / 16 * 2 - 1, (col + 0.5) / 12 * 2 - 1
            for c in range(3):
                d = np.array([np.cos(angles[c]), np.sin(angles[c])])
                t = (v * d[0] + u * d[1]) / np.abs(d).max()
                expected[r, col, c] = np.clip(np.rint(image[r, col, c] * (1 + slopes[c] * t)), 0, 255)
    np.testing.assert_array_equal(out, expected)
    flat = np.full((16, 12, 3), 100, np.uint8)
    ramp = check.shade_image(flat, slopes, angles).astype(int)
    assert ramp[-1, :, 0].min() >= 104 and ramp[0, :, 0].max() <= 96  # channel 0 brighter towards the last row
    assert ramp[:, -1, 1].min() >= 109 and ramp[:, 0, 1].max() <= 91  # channel 1 towards the last column


@pytest.mark.parametrize("condition", ["shading", "shading10"])
def test_shading_changes_the_light_unevenly_and_keeps_the_old_no_contact_image(condition):
    s = small_set()
    flat = replace(s, images=np.full(s.images.shape, 120, np.uint8))
    out = check.real_set_up(flat, condition, BACKGROUND, np.random.default_rng(0))
    np.testing.assert_array_equal(out.backgrounds, np.broadcast_to(BACKGROUND, out.backgrounds.shape))
    np.testing.assert_array_equal(out.T_world_sensors, s.T_world_sensors)
    slope = check.SHADING[condition]
    for image in out.images.reshape(-1, 320, 240, 3):
        halves = [image[:160].mean(axis=(0, 1)), image[160:].mean(axis=(0, 1)),
                  image[:, :120].mean(axis=(0, 1)), image[:, 120:].mean(axis=(0, 1))]
        spread = np.max(np.abs(np.subtract(halves[0], halves[1])) + np.abs(np.subtract(halves[2], halves[3])))
        assert 0.5 * 120 * slope < spread < 2.5 * 120 * slope  # the halves differ by about the slope
        assert abs(image.mean() - 120) < 1.0  # about unchanged on average: uneven, not brighter


def test_the_size_conditions_give_the_images_at_another_resolution():
    """tacto-size and vga leave the set as it is (the images are resized when estimated): at_size averages 2 x 2
    blocks down to 120 x 160 and enlarges to 480 x 640, keeping the leading axes."""
    s = small_set()
    assert all(check.real_set_up(s, c, BACKGROUND, np.random.default_rng(0)) is s for c in check.SIZES)
    small = check.at_size(s.images, *check.SIZES["tacto-size"])
    assert small.shape == (3, 3, 160, 120, 3) and small.dtype == np.uint8
    naive = s.images.reshape(3, 3, 160, 2, 120, 2, 3).astype(float).mean(axis=(3, 5))
    assert np.abs(small - naive).max() <= 0.5 + 1e-9
    large = check.at_size(s.images[0, 0], *check.SIZES["vga"])
    assert large.shape == (640, 480, 3)
    assert abs(large.astype(float).mean() - s.images[0, 0].mean()) < 0.5


def test_the_confidence_row_against_a_naive_count():
    confidence = np.array([0.9, 0.8, np.nan, 0.3, 0.6, 0.2])
    ambiguous = np.array([False, True, False, False, True, False])
    adi = np.array([0.002, 0.004, np.nan, 0.03, 0.012, 0.001])  # m; the third failed
    row = check.confidence_row(confidence, ambiguous, adi)
    right = [0.9, 0.8, 0.2]  # ADI under 1 cm
    wrong = [0.0, 0.3, 0.6]  # the failed estimate counts as wrong, at confidence 0
    pairs = [(r > w) + 0.5 * (r == w) for r in right for w in wrong]
    assert row["confidence_auroc"] == pytest.approx(np.mean(pairs), abs=1e-3)
    assert row["share_right_pct"] == 50.0 and row["ambiguous_pct"] == pytest.approx(100 / 3, abs=0.1)
    assert row["mean_confidence_pct"] == pytest.approx(100 * (0.9 + 0.8 + 0.3 + 0.6 + 0.2) / 6, abs=0.1)


def test_the_recording_estimator_keeps_the_last_estimate_and_forgets_it_when_one_raises():
    class Stub:
        def __init__(self):
            self.calls = 0

        def estimate(self, *args, **kwargs):
            self.calls += 1
            if self.calls == 2:
                raise ValueError("no match")
            return ("estimate", args, kwargs)

    recorder = check.RecordingEstimator(Stub())
    assert recorder.estimate(1, 2, backgrounds=3) == ("estimate", (1, 2), {"backgrounds": 3}) == recorder.last
    with pytest.raises(ValueError):
        recorder.estimate(4)
    assert recorder.last is None
