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


@pytest.mark.parametrize("extra", ["pose_error_translation", "backgrounds"])
def test_a_set_whose_images_are_not_renders_at_its_poses_is_refused(tmp_path, extra):
    shape = (2, 3, 320, 240, 3) if extra == "backgrounds" else (2, 3, 3)
    scenes = _scene_set(extra={extra: np.zeros(shape, dtype=np.uint8 if extra == "backgrounds" else float)})
    source = _write(tmp_path / "artifacts", "kinematic", scenes)
    with pytest.raises(SystemExit, match=extra):
        tacto_scenes.read_set(source)


def test_the_scratch_folder_reads_as_the_artifacts_but_for_its_own_scenes(tmp_path):
    artifacts = tmp_path / "artifacts"
    _write(artifacts, "validation", _scene_set())
    (artifacts / "ae").mkdir()
    (artifacts / "ae" / "weights.pt").write_text("w")
    out = tmp_path / "out"
    tacto_scenes.link_artifacts(artifacts, out)
    tacto_scenes.link_artifacts(artifacts, out)  # again: what is there is kept
    assert (out / "ae").is_symlink() and (out / "ae" / "weights.pt").read_text() == "w"
    assert not (out / "scenes").is_symlink() and (out / "scenes" / "validation.h5").is_symlink()
    (out / "scenes" / "validation_tacto.h5").write_text("x")
    assert sorted(p.name for p in (artifacts / "scenes").iterdir()) == ["validation.h5"]


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
    moved = dict(b, T_world_object=a["T_world_object"] + 1)
    with pytest.raises(SystemExit, match="T_world_object"):
        compare_images.compare_sets(a, moved, background)
