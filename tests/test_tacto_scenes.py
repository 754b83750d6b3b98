"""scripts/tacto_scenes.py without TACTO (it runs in its own environment, `make tacto-env`): the poses handed to
TACTO, the scene set written back, the sets it refuses and the scratch folder beside the pipeline's artifacts;
scripts/compare_scene_images.py, which compares such a set's images with the set it was rendered from."""

import json

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from script_loader import load_script

from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.sim.scenes import SceneSet, scene_set_from_artifact

tacto_scenes = load_script("tacto_scenes")


def test_the_orientation_is_tactos_euler_convention():
    """TACTO's ``euler2matrix`` builds a node's pose as ``Rotation.from_euler("xyz", angles)``: the angles handed
    to it must give back the scene's rotation, whatever the rotation (near gimbal lock included)."""
    rotations = Rotation.random(200, random_state=0).as_matrix()
    rotations[0] = Rotation.from_euler("xyz", [0.3, np.pi / 2, -1.0]).as_matrix()
    for i, R in enumerate(rotations):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, [0.01 * i, -0.02, 0.2]
        position, angles = tacto_scenes.euler_xyz(T)
        assert np.allclose(Rotation.from_euler("xyz", angles).as_matrix(), R, atol=1e-9)
        assert np.array_equal(position, T[:3, 3])


def _scene_set(n=2, extra=None):
    rng = np.random.default_rng(3)
    T_sensors = np.tile(np.eye(4), (n, 3, 1, 1))
    T_sensors[..., :3, 3] = rng.normal(0, 0.05, (n, 3, 3))
    return SceneSet(names=np.array([f"s{i}" for i in range(n)]), objects=np.array(["004_sugar_box"] * n),
                    T_world_object=np.tile(np.eye(4), (n, 1, 1)), T_world_sensors=T_sensors,
                    images=rng.integers(0, 256, (n, 3, 320, 240, 3), dtype=np.uint8),
                    contact_points=rng.normal(size=(n, 3, 3)), contact_normals=rng.normal(size=(n, 3, 3)),
                    contact_types=np.zeros((n, 3), dtype=np.int64), extra=extra or {})


def _write(artifacts, name, scenes):
    config = {"render": {"background": "digit/caddeo2023/background.png"}}
    path = layout.scenes_file(artifacts, name)
    write_artifact(path, "scenes", scenes.as_datasets(), attrs={"scene_set": name}, config=config)
    return path


def test_the_set_written_reads_as_the_same_scenes_with_the_new_images(tmp_path):
    scenes = _scene_set()
    source = _write(tmp_path / "artifacts", "validation", scenes)
    datasets, attrs = tacto_scenes.read_set(source)
    new = np.full_like(scenes.images, 7)
    target = tmp_path / "out" / "scenes" / "validation_tacto.h5"
    name = tacto_scenes.write_images_as_set(datasets, attrs, new, target, "tacto", {"tool": "test"})
    assert name == "validation_tacto"
    art = read_artifact(target, "scenes")
    back = scene_set_from_artifact(art)
    assert np.array_equal(back.images, new)
    for field in ("T_world_object", "T_world_sensors", "contact_points", "contact_normals", "contact_types"):
        assert np.array_equal(getattr(back, field), getattr(scenes, field))
    assert list(back.names) == list(scenes.names) and list(back.objects) == list(scenes.objects)
    assert art.config == {"render": {"background": "digit/caddeo2023/background.png"}}
    with h5py.File(target) as f:
        assert json.loads(f.attrs["scene_set"]) == "validation_tacto"
        assert json.loads(f.attrs["renderer"]) == {"tool": "test"}
    with pytest.raises(ValueError, match="images"):
        tacto_scenes.write_images_as_set(datasets, attrs, new[:1], target, "tacto", {})
    # at TACTO's own default size the images are kept as a camera of that size gives them
    small = np.full((2, 3, 160, 120, 3), 9, np.uint8)
    tacto_scenes.write_images_as_set(datasets, attrs, small, tmp_path / "small.h5", "tacto", {"size": [120, 160]})
    assert np.array_equal(scene_set_from_artifact(read_artifact(tmp_path / "small.h5", "scenes")).images, small)


@pytest.mark.parametrize("extra", ["pose_error_translation", "backgrounds"])
def test_a_set_whose_images_are_not_renders_at_its_poses_is_refused(tmp_path, extra):
    shape = (2, 3, 320, 240, 3) if extra == "backgrounds" else (2, 3, 3)
    scenes = _scene_set(extra={extra: np.zeros(shape, dtype=np.uint8 if extra == "backgrounds" else float)})
    source = _write(tmp_path / "artifacts", "kinematic", scenes)
    with pytest.raises(SystemExit, match=extra):
        tacto_scenes.read_set(source)


def test_the_scratch_folder_reads_as_the_artifacts_but_writes_apart_from_them(tmp_path):
    artifacts = tmp_path / "artifacts"
    _write(artifacts, "validation", _scene_set())
    for folder, name in (("ae", "weights.pt"), ("sequences", "tracking.h5"), ("metrics", "tracking.json")):
        (artifacts / folder).mkdir()
        (artifacts / folder / name).write_text(folder)
    out = tmp_path / "out"
    tacto_scenes.link_artifacts(artifacts, out)
    tacto_scenes.link_artifacts(artifacts, out)  # again: what is there is kept
    assert (out / "ae").is_symlink() and (out / "ae" / "weights.pt").read_text() == "ae"
    for folder in ("scenes", "sequences", "metrics", "times"):
        assert (out / folder).is_dir() and not (out / folder).is_symlink()
    assert (out / "scenes" / "validation.h5").is_symlink() and (out / "sequences" / "tracking.h5").is_symlink()
    # what a stage run on the scratch folder writes stays there
    assert list((out / "metrics").iterdir()) == [] and list((out / "times").iterdir()) == []
    (out / "scenes" / "validation_tacto.h5").write_text("x")
    assert sorted(p.name for p in (artifacts / "scenes").iterdir()) == ["validation.h5"]
    linked_by_hand = tmp_path / "by_hand"
    linked_by_hand.mkdir()
    (linked_by_hand / "metrics").symlink_to(artifacts / "metrics")
    with pytest.raises(SystemExit, match="metrics"):
        tacto_scenes.link_artifacts(artifacts, linked_by_hand)


def test_sequences_are_rendered_frame_by_frame_at_the_poses_their_images_were_made_at():
    """A sequence set's frames in order, each at its true sensor poses (not those the hand reports); a scene
    set's scenes at its sensor poses."""
    rng = np.random.default_rng(0)
    S, F, L = 2, 4, 3
    sequences = {"images": np.zeros((S, F, L, 320, 240, 3), np.uint8),
                 "T_world_object": rng.normal(size=(S, F, 4, 4)),
                 "T_world_sensors": rng.normal(size=(S, F, L, 4, 4)),
                 "T_world_sensors_true": rng.normal(size=(S, F, L, 4, 4))}
    T_objects, T_sensors, lead = tacto_scenes.rendered_poses(sequences)
    assert lead == (S, F, L) and T_objects.shape == (S * F, 4, 4) and T_sensors.shape == (S * F, L, 4, 4)
    assert np.array_equal(T_objects[F + 2], sequences["T_world_object"][1, 2])
    assert np.array_equal(T_sensors[F + 2], sequences["T_world_sensors_true"][1, 2])
    scenes = _scene_set(n=3).as_datasets()
    T_objects, T_sensors, lead = tacto_scenes.rendered_poses(scenes)
    assert lead == (3, 3) and np.array_equal(T_sensors, scenes["T_world_sensors"])


compare_images = load_script("compare_scene_images")


def _pressed(background, centre, radius):
    """background (H, W, 3) with a disc brightened by 30 grey levels: a press as the masks see it."""
    yy, xx = np.mgrid[: background.shape[0], : background.shape[1]]
    image = background.astype(np.int16)
    image[(yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 < radius**2] += 30
    return np.clip(image, 0, 255).astype(np.uint8)


def test_two_renderings_of_the_same_scenes_are_compared_pair_by_pair():
    background = np.full((320, 240, 3), 100, np.uint8)
    a = {"T_world_object": np.tile(np.eye(4), (1, 1, 1)), "T_world_sensors": np.tile(np.eye(4), (1, 3, 1, 1))}
    b = dict(a)
    a["images"] = np.stack([[_pressed(background, (160, 120), 40), _pressed(background, (100, 100), 30), background]])
    b["images"] = np.stack([[_pressed(background, (160, 120), 40), background, background]])
    row = compare_images.compare_sets(a, b, background)
    # the first pair the same press (IoU 1), the second a press against none (IoU 0; contact disagrees), the
    # third untouched in both: left out of the IoU
    assert row["pairs"] == 3 and row["contact_disagrees"] == pytest.approx(1 / 3, abs=1e-3)
    assert row["iou_median"] == pytest.approx(0.5) and row["iou_p10"] == pytest.approx(0.1)
    # the same press in both: as strong (1); a press against none: nothing (0); their median
    assert row["strength_ratio_median"] == pytest.approx(0.5, abs=1e-6)
    # a press twice as bright in the second set, the same masks: IoU 1 and correlation 1 do not see it, the ratio does
    once = _pressed(background, (160, 120), 40)
    twice = _pressed(once, (160, 120), 40)
    row = compare_images.compare_sets(dict(a, images=np.stack([[once] * 3])), dict(b, images=np.stack([[twice] * 3])),
                                      background)
    assert row["corr_median"] == pytest.approx(1.0) and row["strength_ratio_median"] == pytest.approx(2.0, rel=1e-3)
    moved = dict(b, T_world_object=a["T_world_object"] + 1)
    with pytest.raises(SystemExit, match="T_world_object"):
        compare_images.compare_sets(a, moved, background)



def test_the_montage_shows_the_first_sensor_of_scenes_spread_over_the_set(tmp_path):
    import cv2

    background = np.full((320, 240, 3), 100, np.uint8)
    pressed = np.stack([_pressed(background, (160, 120), 20 + 10 * i) for i in range(5)])
    a = {"images": np.stack([pressed, pressed, pressed], axis=1), "objects": np.array([b"x"] * 5)}
    b = {"images": a["images"].copy(), "objects": a["objects"]}
    b["images"][4, 0] = background  # the last scene's first sensor: no press in the second set
    compare_images.write_montage(tmp_path / "m.png", a, b, background, 3, ("TACTO", "ours"))
    image = cv2.imread(str(tmp_path / "m.png"))
    assert image.shape == (3 * (320 + 20), 3 * 240, 3)
    # scenes 0, 2 and 4: the first two rows' difference panels flat grey, the last one's showing the press
    differences = [image[r * 340 + 20 : (r + 1) * 340, 480:].astype(int) for r in range(3)]
    assert [np.abs(d - 128).max() for d in differences][:2] == [0, 0] and np.abs(differences[2] - 128).max() > 50


def test_a_sequence_set_is_written_under_its_own_name_attribute(tmp_path):
    datasets = {"images": np.zeros((1, 2, 3, 320, 240, 3), np.uint8), "fps": np.array(30.0)}
    attrs = {"schema": "sequences", "sequence_set": json.dumps("tracking")}
    new = np.ones_like(datasets["images"])
    name = tacto_scenes.write_images_as_set(datasets, attrs, new, tmp_path / "tracking.h5", "tacto", {"seed": 0})
    with h5py.File(tmp_path / "tracking.h5") as f:
        assert name == "tracking_tacto" and json.loads(f.attrs["sequence_set"]) == "tracking_tacto"
        assert "scene_set" not in f.attrs and np.array_equal(f["images"][()], new) and f["fps"][()] == 30.0


def test_a_deeper_press_moves_each_sensor_along_its_own_axis():
    rotations = Rotation.random(6, random_state=1).as_matrix().reshape(2, 3, 3, 3)
    T = np.tile(np.eye(4), (2, 3, 1, 1))
    T[..., :3, :3] = rotations
    T[..., :3, 3] = np.random.default_rng(1).normal(0, 0.05, (2, 3, 3))
    moved = tacto_scenes.pressed_further(T, 0.0015)
    # in each sensor's own frame the move is +1.5 mm along x; orientations and the input are left alone
    local = np.linalg.inv(T) @ moved
    assert np.allclose(local[..., :3, 3], [0.0015, 0.0, 0.0], atol=1e-12)
    assert np.array_equal(moved[..., :3, :3], T[..., :3, :3]) and not np.shares_memory(moved, T)
    assert np.allclose(tacto_scenes.pressed_further(moved, -0.0015), T, atol=1e-12)


@pytest.mark.slow
def test_the_contact_patches_read_from_both_sets_are_compared():
    from test_estimator import small_patch_model

    background = np.full((320, 240, 3), 100, np.uint8)
    poses = {"T_world_object": np.tile(np.eye(4), (1, 1, 1)), "T_world_sensors": np.tile(np.eye(4), (1, 3, 1, 1))}
    here, there = _pressed(background, (160, 120), 40), _pressed(background, (200, 120), 40)
    a = dict(poses, images=np.stack([[here, here, background]]))
    b = dict(poses, images=np.stack([[here, there, background]]))
    row = compare_images.compare_sets(a, b, background, small_patch_model())
    # pairs with contact in both: the same press (0 apart) and one moved 40 pixels down the image (millimetres)
    assert row["contact_point_mm_median"] > 0 and row["contact_point_mm_p90"] > 1.0
    same = compare_images.compare_sets(a, a, background, small_patch_model())
    assert same["contact_point_mm_p90"] == 0.0 and same["normal_deg_p90"] == 0.0
    assert "contact_point_mm_median" not in compare_images.compare_sets(a, b, background)
