"""tactile6d.sim.perturb: a clean scene set as a real set-up gives it (drifted light, kinematic error), and the
scene artifact that carries each sensor's own no-contact image."""

import numpy as np
import pytest

from tactile6d.core.geometry import invert_pose, make_pose, rotmat_to_rotvec
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.sim import perturb
from tactile6d.sim.scenes import SceneSet, scene_set_from_artifact

S, L, H, W = 8, 3, 320, 240


def clean_set() -> tuple[SceneSet, np.ndarray]:
    """8 scenes of 3 sensors pressing a square into a colourful background, and that background."""
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:H, 0:W]
    background = np.stack([60 + cols // 3, 70 + rows // 4, 170 - (rows + cols) // 5], axis=-1).astype(np.uint8)
    images = np.broadcast_to(background, (S, L, H, W, 3)).copy()
    images[:, :, 100:200, 80:160] += 30  # a press
    T_sensors = np.broadcast_to(make_pose(np.eye(3), [0.1, 0.0, 0.2]), (S, L, 4, 4)).copy()
    T_sensors[..., :3, 3] += rng.normal(0, 0.03, (S, L, 3))
    return SceneSet(np.array([f"s{i}" for i in range(S)]), np.array(["box"] * S),
                    np.broadcast_to(np.eye(4), (S, 4, 4)).copy(), T_sensors, images,
                    rng.normal(size=(S, L, 3)), rng.normal(size=(S, L, 3)), np.zeros((S, L), np.int64)), background


def test_drifted_light_keeps_the_truth_and_gives_each_sensor_the_no_contact_image_a_user_has():
    clean, background = clean_set()
    out = perturb.drift_light(clean, background, 0.1, (0.83, 1.2), 2.0, 0.5, np.random.default_rng(1))
    for key in ("names", "objects", "T_world_object", "T_world_sensors", "contact_points", "contact_normals"):
        assert np.array_equal(getattr(out, key), getattr(clean, key))
    gains, gammas, again = out.extra["light_gain"], out.extra["light_gamma"], out.extra["background_rerecorded"]
    assert gains.shape == gammas.shape == (S, L, 3) and again.shape == (S,)
    assert np.all(np.abs(gains - 1) <= 0.1) and np.all((gammas >= 0.83) & (gammas <= 1.2))
    assert 0 < again.sum() < S  # with half re-recorded, some of 8 scenes are and some are not
    for s in range(S):
        for i in range(L):
            expected = perturb.drift_image_light(clean.images[s, i], gains[s, i], gammas[s, i])
            assert np.abs(out.images[s, i].astype(int) - expected).mean() < 2.5  # plus noise of sigma 2
            if again[s]:  # recorded again under the drifted light
                drifted = perturb.drift_image_light(background, gains[s, i], gammas[s, i]).astype(int)
                assert np.abs(out.backgrounds[s, i].astype(int) - drifted).mean() < 2.5
            else:  # the no-contact image of before the drift
                assert np.array_equal(out.backgrounds[s, i], background)


def test_kinematic_error_moves_each_sensor_pose_in_its_own_frame_by_the_drawn_error():
    clean, _ = clean_set()
    out = perturb.perturb_sensor_poses(clean, 0.0015, np.radians(1.5), np.random.default_rng(2))
    assert np.array_equal(out.images, clean.images)
    error = invert_pose(clean.T_world_sensors) @ out.T_world_sensors  # (S, L, 4, 4), sensor frame
    assert np.allclose(error[..., :3, 3], out.extra["pose_error_translation"])
    assert np.allclose(rotmat_to_rotvec(error[..., :3, :3]), out.extra["pose_error_rotvec"])
    assert 0.0005 < np.std(out.extra["pose_error_translation"]) < 0.003


def test_a_scene_set_with_its_own_backgrounds_round_trips_through_its_artifact(tmp_path):
    clean, background = clean_set()
    out = perturb.drift_light(clean, background, 0.1, (0.83, 1.2), 2.0, 0.5, np.random.default_rng(3))
    path = write_artifact(tmp_path / "variation.h5", "scenes", out.as_datasets())
    back = scene_set_from_artifact(read_artifact(path, "scenes"))
    assert np.array_equal(back.backgrounds, out.backgrounds) and np.array_equal(back.images, out.images)
    assert np.array_equal(back.extra["light_gain"], out.extra["light_gain"])
    assert np.array_equal(back.backgrounds_of(2), out.backgrounds[2])
    plain = scene_set_from_artifact(read_artifact(write_artifact(tmp_path / "plain.h5", "scenes", clean.as_datasets()),
                                                  "scenes"))
    assert plain.backgrounds is None and plain.backgrounds_of(0) is None and plain.extra == {}


@pytest.mark.parametrize("noise", [0.0, 3.0])
def test_camera_noise_has_its_sigma(noise):
    image = np.full((200, 200, 3), 128, np.uint8)
    out = perturb.add_camera_noise(image, noise, np.random.default_rng(4)).astype(float)
    assert abs(out.std() - noise) < 0.1


def test_the_jpeg_round_trip_is_opencvs_encode_and_decode_in_rgb():
    """Against the naive round trip through a file: BGR on disk as OpenCV writes it, RGB in memory."""
    import cv2

    clean, _ = clean_set()
    image = clean.images[0, 0]
    ok, encoded = cv2.imencode(".jpg", image[..., ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 80])
    naive = cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(perturb.jpeg_round_trip(image, 80), naive)
    assert np.abs(perturb.jpeg_round_trip(image, 80).astype(int) - image).mean() < 2  # smooth: little lost


def test_defocus_is_a_normalised_gaussian_of_its_sigma():
    """A single bright pixel spreads into the Gaussian's kernel, its sum kept; sigma 0 leaves the image."""
    image = np.zeros((H, W, 3), np.uint8)
    image[160, 120] = 255
    out = perturb.defocus(image, 1.0).astype(float)
    assert out[..., 0].sum() == pytest.approx(255, abs=8)  # rounding of the 49 taps
    assert np.count_nonzero(out[..., 0]) <= 49 and out[160, 120, 0] == out[..., 0].max()
    ratio = out[160, 121, 0] / out[160, 120, 0]
    assert ratio == pytest.approx(np.exp(-0.5), abs=0.03)
    np.testing.assert_array_equal(perturb.defocus(image, 0.0), image)


def test_through_camera_treats_each_sensors_own_no_contact_image_like_its_images():
    clean, background = clean_set()
    out = perturb.through_camera(clean, background, jpeg_quality=70, blur_sigma=1.0)
    expected = perturb.jpeg_round_trip(perturb.defocus(clean.images[2, 1], 1.0), 70)
    np.testing.assert_array_equal(out.images[2, 1], expected)
    np.testing.assert_array_equal(out.backgrounds[3, 0], perturb.jpeg_round_trip(perturb.defocus(background, 1.0), 70))
    own = np.broadcast_to(background[::-1], clean.images.shape).copy()  # a set that carries its own
    from dataclasses import replace

    again = perturb.through_camera(replace(clean, backgrounds=own), background, jpeg_quality=70)
    np.testing.assert_array_equal(again.backgrounds[0, 2], perturb.jpeg_round_trip(own[0, 2], 70))
    np.testing.assert_array_equal(out.T_world_object, clean.T_world_object)
