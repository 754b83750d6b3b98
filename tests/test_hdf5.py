import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from tactile6d.core.errors import ArtifactError
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.schemas import SCHEMAS


def surface_data(n=10):
    rng = np.random.default_rng(0)
    return {"points": rng.normal(size=(n, 3)), "normals": rng.normal(size=(n, 3)), "face_index": np.arange(n)}


def test_round_trip_keeps_data_stamp_and_config(tmp_path):
    path = write_artifact(tmp_path / "s.h5", "surface", surface_data(), attrs={"object": "x"}, config={"sample": {"M": 10}})
    art = read_artifact(path, "surface")
    np.testing.assert_array_equal(art["points"], surface_data()["points"])
    assert art.config == {"sample": {"M": 10}}
    assert art.attrs["object"] == "x"
    assert [p.name for p in tmp_path.iterdir()] == ["s.h5"]  # no temporary file left


def test_written_files_get_the_mode_open_would_give_them_not_a_temporary_files(tmp_path):
    """The atomic writers' temporary files are private (0o600); what they become is readable as any new file."""
    from tactile6d.data.hdf5 import write_json, write_text

    umask = os.umask(0o022)
    os.umask(umask)
    expected = 0o666 & ~umask
    for path in (write_artifact(tmp_path / "s.h5", "surface", surface_data()), write_text(tmp_path / "t.txt", "x\n"),
                 write_json(tmp_path / "m.json", {"a": 1})):
        assert path.stat().st_mode & 0o777 == expected, path
    opened = tmp_path / "opened.txt"
    opened.write_text("x")
    assert opened.stat().st_mode & 0o777 == expected


def test_missing_artifact_names_the_stage(tmp_path):
    with pytest.raises(ArtifactError, match=r"missing.*sample_surface.*dvc repro sample_surface"):
        read_artifact(tmp_path / "nope.h5", "surface")


def test_corrupt_artifact_gives_a_clear_error(tmp_path):
    path = write_artifact(tmp_path / "s.h5", "surface", surface_data())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])  # truncated, as by a disk-full copy
    with pytest.raises(ArtifactError, match=r"s\.h5: unreadable or corrupt HDF5.*sample_surface"):
        read_artifact(path, "surface")
    path.write_bytes(b"not hdf5 at all")
    with pytest.raises(ArtifactError, match="unreadable or corrupt"):
        read_artifact(path, "surface")


def test_wrong_schema_is_named(tmp_path):
    path = write_artifact(tmp_path / "s.h5", "surface", surface_data())
    with pytest.raises(ArtifactError, match=r"schema is 'surface' but 'object' was expected.*prepare_object"):
        read_artifact(path, "object")


def test_an_older_format_is_refused_naming_the_stage_that_remakes_it(tmp_path):
    # A training set from before contact_types (schema version 1) must not reach train_ae.
    path = write_artifact(tmp_path / "t.h5", "surface", surface_data())
    with h5py.File(path, "r+") as f:
        f.attrs["schema"], f.attrs["schema_version"] = "training_set", 1
    with pytest.raises(ArtifactError, match=r"'training_set' version 1, this code reads version 2.*make_training_set"):
        read_artifact(path, "training_set")


def test_every_schema_is_made_by_a_pipeline_stage():
    stages = yaml.safe_load((Path(__file__).parents[1] / "dvc.yaml").read_text())["stages"]
    for schema in SCHEMAS.values():
        assert schema.stage in stages, schema
        assert len(set(schema.datasets)) == len(schema.datasets), schema


def test_writer_refuses_incomplete_data(tmp_path):
    with pytest.raises(ValueError, match="lacks datasets"):
        write_artifact(tmp_path / "s.h5", "surface", {"points": np.zeros((1, 3))})
    assert not list(tmp_path.iterdir())


def test_interrupted_write_leaves_no_file(tmp_path):
    """Kill a writer in the middle of a large write: neither the artifact nor a temp file remains."""
    target = tmp_path / "big.h5"
    script = textwrap.dedent(f"""
        import numpy as np, sys
        import tactile6d.data.hdf5 as io
        class Slow(dict):
            pass
        big = np.zeros((4000, 1000, 3))
        data = {{"points": big, "normals": big, "face_index": np.arange(4000)}}
        orig = io.h5py.File.create_dataset if hasattr(io.h5py.File, "create_dataset") else None
        import h5py
        real = h5py.Group.create_dataset
        def slow(self, *a, **k):
            print("writing", flush=True)
            import time; time.sleep(30)
            return real(self, *a, **k)
        h5py.Group.create_dataset = slow
        io.write_artifact({str(target)!r}, "surface", data)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                            cwd=os.path.dirname(os.path.dirname(__file__)))
    assert proc.stdout.readline().strip() == "writing"
    assert list(tmp_path.iterdir())  # the temporary file exists while writing
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # SIGKILL gives no chance to clean up: the temp file may remain, but never the artifact itself.
    assert not target.exists()
    assert all(".tmp-" in p.name for p in tmp_path.iterdir())


def test_exception_during_write_cleans_up(tmp_path, monkeypatch):
    import h5py

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(h5py.Group, "create_dataset", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        write_artifact(tmp_path / "s.h5", "surface", surface_data())
    assert not list(tmp_path.iterdir())


def write_scene(folder, n_sensors=3, n_images=3, shape=(320, 240, 3)):
    from tactile6d.core.geometry import make_pose, poses_to_text
    from tactile6d.data.hdf5 import write_tactile_image

    folder.mkdir(parents=True, exist_ok=True)
    poses = np.stack([make_pose(np.eye(3), [0.01 * i, 0, 0]) for i in range(n_sensors)])
    (folder / "poses_sensors.txt").write_text(poses_to_text(poses))
    rng = np.random.default_rng(0)
    for i in range(n_images):
        write_tactile_image(folder / f"Image_heatmap_{i}.png", rng.integers(0, 255, shape, dtype=np.uint8))
    return poses


def test_scene_dir_round_trip(tmp_path):
    from tactile6d.data.hdf5 import read_scene_dir, read_tactile_image, write_tactile_image

    poses = write_scene(tmp_path / "s")
    T, images = read_scene_dir(tmp_path / "s")
    np.testing.assert_allclose(T, poses, atol=1e-12)
    assert images.shape == (3, 320, 240, 3) and images.dtype == np.uint8
    img = np.zeros((320, 240, 3), np.uint8)
    img[..., 0] = 200  # pure red stays red (RGB in memory, whatever the file's byte order)
    write_tactile_image(tmp_path / "red.png", img)
    assert read_tactile_image(tmp_path / "red.png")[0, 0].tolist() == [200, 0, 0]


def test_scene_dir_errors(tmp_path):
    from tactile6d.core.errors import InputError
    from tactile6d.data.hdf5 import read_scene_dir

    with pytest.raises(InputError, match="not found"):
        read_scene_dir(tmp_path / "absent")
    write_scene(tmp_path / "few", n_sensors=3, n_images=2)
    with pytest.raises(InputError, match="Image_heatmap_2.png missing"):
        read_scene_dir(tmp_path / "few")
    write_scene(tmp_path / "square", shape=(160, 160, 3))
    with pytest.raises(InputError, match="160 wide x 160 high, a DIGIT image is 240 wide x 320 high"):
        read_scene_dir(tmp_path / "square")
    (tmp_path / "nopose").mkdir()
    with pytest.raises(InputError, match="poses_sensors.txt missing"):
        read_scene_dir(tmp_path / "nopose")
    bad = tmp_path / "nan"
    write_scene(bad)
    (bad / "poses_sensors.txt").write_text("0 0 0 1 0 0 nan\n" * 3)
    with pytest.raises(InputError, match="NaN"):
        read_scene_dir(bad)


def test_reads_the_papers_triplets(data_dir):
    from tactile6d.data.hdf5 import read_scene_dir

    T, images = read_scene_dir(data_dir / "caddeo2023/triplets/004_sugar_box/triplet_1")
    assert T.shape == (3, 4, 4) and images.shape == (3, 320, 240, 3)


def test_resize_to_tactile_against_block_means_and_bilinear_references():
    """Shrinking by 2 is the mean of each 2 x 2 block (rounded); enlarging a linear ramp keeps it linear inside;
    the shape only tells what is resizable (4:3 rows to columns, three channels)."""
    from tactile6d.data.hdf5 import resizable_to_tactile, resize_to_tactile

    rng = np.random.default_rng(0)
    vga = rng.integers(0, 256, (640, 480, 3), dtype=np.uint8)
    naive = vga.reshape(320, 2, 240, 2, 3).astype(np.float64).mean(axis=(1, 3))
    small = resize_to_tactile(vga)
    assert small.shape == (320, 240, 3) and small.dtype == np.uint8
    assert np.abs(small - naive).max() <= 0.5 + 1e-9
    rows = np.arange(160, dtype=np.float64)
    ramp = np.repeat(rows[:, None, None], 120, axis=1).repeat(3, axis=2).astype(np.uint8)
    big = resize_to_tactile(ramp)
    # bilinear with half-pixel centres: output row r samples input row (r + 0.5) / 2 - 0.5
    expected = (np.arange(320) + 0.5) / 2 - 0.5
    np.testing.assert_allclose(big[2:-2, 100, 0], expected[2:-2], atol=0.5 + 1e-9)
    assert resizable_to_tactile((640, 480, 3)) and resizable_to_tactile((160, 120, 3))
    assert not resizable_to_tactile((320, 240, 3))  # already the DIGIT's size
    assert not resizable_to_tactile((480, 640, 3))  # turned: the camera's raw frame
    assert not resizable_to_tactile((640, 480, 4)) and not resizable_to_tactile((640, 480))
    assert not resizable_to_tactile((600, 480, 3))


def test_an_image_file_at_another_size_is_read_resized_and_said(tmp_path):
    import warnings

    import cv2

    from tactile6d.core.errors import InputError
    from tactile6d.data.hdf5 import ImageSizeWarning, read_tactile_image

    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (320, 240, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "vga.png"), image.repeat(2, axis=0).repeat(2, axis=1)[..., ::-1])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read = read_tactile_image(tmp_path / "vga.png")
    np.testing.assert_array_equal(read, image)
    (w,) = caught
    assert w.category is ImageSizeWarning and (w.message.width, w.message.height) == (480, 640)
    assert w.message.name == str(tmp_path / "vga.png")
    assert str(w.message).endswith("vga.png is 480 wide x 640 high: read resized to the DIGIT's 240 x 320 (averaged down)")
    cv2.imwrite(str(tmp_path / "wide.png"), np.zeros((320, 320, 3), np.uint8))
    with pytest.raises(InputError, match=r"wide.png is 320 wide x 320 high, .*an image of its proportions at another "
                                         r"size .* is read resized"):
        read_tactile_image(tmp_path / "wide.png")


def test_a_size_problem_hints_by_shape_turned_or_resizable():
    """A turned DIGIT image (the raw frame's proportions, at any size) gets the rotation hint and not the resize one;
    a colour image of other proportions gets the resize one; an accepted shape none; sized_as_tactile passes an image
    at the DIGIT's size through unchanged (the same object) and resizes another with a warning naming it."""
    import warnings

    from tactile6d.data.hdf5 import ImageSizeWarning, sized_as_tactile, tactile_size_problem

    for turned in [(240, 320, 3), (480, 640, 3)]:
        problem = tactile_size_problem(turned, "im")
        assert "np.rot90(frame)" in problem and "read resized" not in problem
    assert "read resized" in tactile_size_problem((300, 300, 3), "im")
    assert "read resized" not in tactile_size_problem((320, 240, 4), "im")  # four channels: not the size at fault
    assert tactile_size_problem((320, 240, 3), "im") is None and tactile_size_problem((640, 480, 3), "im") is None
    image = np.zeros((320, 240, 3), np.uint8)
    assert sized_as_tactile(image, "im") is image
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        small = sized_as_tactile(np.zeros((160, 120, 3), np.uint8), "tacto")
    assert small.shape == (320, 240, 3)
    (w,) = caught
    assert w.category is ImageSizeWarning and (w.message.name, w.message.width, w.message.height) == ("tacto", 120, 160)


def test_a_scene_folder_may_hold_jpeg_images(tmp_path):
    """Image_heatmap_<i> and background_<i> are read from a .jpg or .jpeg where the .png is absent (the images
    JPEG decodes to); two files for one image are an error that names both."""
    import cv2

    from tactile6d.core.errors import InputError
    from tactile6d.data.hdf5 import read_scene_backgrounds, read_scene_dir

    folder = tmp_path / "jpeg"
    write_scene(folder)
    rng = np.random.default_rng(2)
    for i, suffix in enumerate([".jpg", ".jpeg", ".png"]):
        image = rng.integers(0, 256, (320, 240, 3), dtype=np.uint8)
        if suffix != ".png":
            (folder / f"Image_heatmap_{i}.png").unlink()
            cv2.imwrite(str(folder / f"Image_heatmap_{i}{suffix}"), image)
        cv2.imwrite(str(folder / f"background_{i}{suffix}"), image)
    _, images = read_scene_dir(folder)
    decoded = cv2.imread(str(folder / "Image_heatmap_0.jpg"))[..., ::-1]
    np.testing.assert_array_equal(images[0], decoded)
    backgrounds = read_scene_backgrounds(folder, 3)
    np.testing.assert_array_equal(backgrounds[1], cv2.imread(str(folder / "background_1.jpeg"))[..., ::-1])
    cv2.imwrite(str(folder / "Image_heatmap_0.png"), images[0][..., ::-1])
    with pytest.raises(InputError, match=r"Image_heatmap_0.png and Image_heatmap_0.jpg are both there"):
        read_scene_dir(folder)
