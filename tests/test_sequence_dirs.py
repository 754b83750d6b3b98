import json

import numpy as np
import pytest

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import make_pose, random_rotations
from tactile6d.data.hdf5 import write_tactile_image
from tactile6d.data.sequence_dirs import iter_sequence_dir, sequence_dir_frames, write_sequence_dir


def sequence(n_frames=3, n_sensors=2, seed=0):
    rng = np.random.default_rng(seed)
    T = make_pose(random_rotations(n_frames * n_sensors, rng).reshape(n_frames, n_sensors, 3, 3),
                  rng.uniform(-0.1, 0.1, size=(n_frames, n_sensors, 3)))
    images = rng.integers(0, 256, size=(n_frames, n_sensors, 320, 240, 3), dtype=np.uint8)
    return T, images, rng


def test_round_trip_with_stamps(tmp_path):
    T, images, _ = sequence()
    stamps = np.array([10.0, 10.05, 10.1])
    write_sequence_dir(tmp_path / "seq", T, images, stamps=stamps)
    frames = list(iter_sequence_dir(tmp_path / "seq"))
    assert [f[0] for f in frames] == [0, 1, 2]
    assert [f[1] for f in frames] == stamps.tolist()
    for f, (index, stamp, T_f, images_f, backgrounds) in enumerate(frames):
        np.testing.assert_allclose(T_f, T[f], atol=1e-12)
        np.testing.assert_array_equal(images_f, images[f])
        assert backgrounds is None
    assert sorted(p.name for p in (tmp_path / "seq" / "000001").iterdir()) == [
        "Image_heatmap_0.png", "Image_heatmap_1.png", "poses_sensors.txt"]


def test_no_frames_json_gives_no_stamps_and_fps_gives_number_over_fps(tmp_path):
    T, images, _ = sequence()
    write_sequence_dir(tmp_path / "a", T, images)
    assert [f[1] for f in iter_sequence_dir(tmp_path / "a")] == [None, None, None]
    write_sequence_dir(tmp_path / "b", T, images, fps=20.0)
    assert json.loads((tmp_path / "b" / "frames.json").read_text()) == {"fps": 20.0}
    assert [f[1] for f in iter_sequence_dir(tmp_path / "b")] == [0.0, 0.05, 0.1]


def test_shared_backgrounds_and_a_frames_own_override_them(tmp_path):
    T, images, rng = sequence()
    shared = rng.integers(0, 256, size=(2, 320, 240, 3), dtype=np.uint8)
    own = rng.integers(0, 256, size=(2, 320, 240, 3), dtype=np.uint8)
    directory = write_sequence_dir(tmp_path / "seq", T, images, backgrounds=shared)
    assert (directory / "background_1.png").is_file()
    for i in range(2):
        write_tactile_image(directory / "000001" / f"background_{i}.png", own[i])
    backgrounds = [f[4] for f in iter_sequence_dir(directory)]
    np.testing.assert_array_equal(backgrounds[0], shared)
    np.testing.assert_array_equal(backgrounds[1], own)
    np.testing.assert_array_equal(backgrounds[2], shared)
    # one sensor's only: named as an error, not mixed with the shared ones
    (directory / "000001" / "background_1.png").unlink()
    with pytest.raises(InputError, match=r"000001: 1 of 2 sensors have a no-contact image.*background_1\.png missing"):
        list(iter_sequence_dir(directory))


def test_per_frame_backgrounds_are_written_into_each_frame(tmp_path):
    T, images, rng = sequence()
    per_frame = rng.integers(0, 256, size=(3, 2, 320, 240, 3), dtype=np.uint8)
    directory = write_sequence_dir(tmp_path / "seq", T, images, backgrounds=per_frame)
    assert not (directory / "background_0.png").exists()
    for f, frame in enumerate(iter_sequence_dir(directory)):
        np.testing.assert_array_equal(frame[4], per_frame[f])


def test_frames_are_in_numeric_order_and_other_entries_ignored(tmp_path):
    T, images, _ = sequence(n_frames=11, n_sensors=1)
    directory = write_sequence_dir(tmp_path / "seq", T, images)
    assert [p.name for p in sequence_dir_frames(directory)][-3:] == ["000008", "000009", "000010"]
    # unpadded names too: "10" sorts before "9" as text
    (directory / "000009").rename(directory / "9")
    (directory / "000010").rename(directory / "10")
    (directory / "notes").mkdir()
    (directory / "000003_old").mkdir()
    (directory / "12.txt").write_text("not a frame")
    assert [p.name for p in sequence_dir_frames(directory)][-3:] == ["000008", "9", "10"]
    frames = list(iter_sequence_dir(directory))
    assert [f[0] for f in frames] == list(range(11))
    np.testing.assert_array_equal(frames[10][3], images[10])
    (directory / "000010").mkdir()
    with pytest.raises(InputError, match=r"seq: frame folders 000010 and 10 have the same number"):
        sequence_dir_frames(directory)


def test_errors_name_the_folder_or_file(tmp_path):
    with pytest.raises(InputError, match=r"sequence folder .*nope not found"):
        sequence_dir_frames(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"empty: no frame folders"):
        iter_sequence_dir(tmp_path / "empty")
    T, images, _ = sequence()
    directory = write_sequence_dir(tmp_path / "seq", T, images, stamps=[0.0, 0.1, 0.2])
    with pytest.raises(InputError, match=r"seq: exists and is not an empty folder"):
        write_sequence_dir(directory, T, images)
    (directory / "frames.json").write_text(json.dumps({"stamps": [0.0, 0.1]}))
    with pytest.raises(InputError, match=r"frames\.json: 2 stamps for 3 frame folders"):
        iter_sequence_dir(directory)
    (directory / "frames.json").write_text(json.dumps({"stamps": [0.0, 0.2, 0.1]}))
    with pytest.raises(InputError, match=r"frames\.json: 'stamps' must be strictly increasing"):
        iter_sequence_dir(directory)
    (directory / "frames.json").write_text(json.dumps({"stamps": [-1.0, 0.1, 0.2]}))
    with pytest.raises(InputError, match=r"frames\.json: 'stamps' must be seconds >= 0 \(ROS time\), got -1.0 for "
                                         r"frame folder 000000"):
        iter_sequence_dir(directory)
    (directory / "frames.json").unlink()
    # a frame with another number of sensors
    (directory / "000002" / "poses_sensors.txt").write_text((directory / "000002" / "poses_sensors.txt").read_text()
                                                              .splitlines()[0] + "\n")
    (directory / "000002" / "Image_heatmap_1.png").unlink()
    with pytest.raises(InputError, match=r"000002: 1 sensors, but the sequence's first frame 000000 has 2"):
        list(iter_sequence_dir(directory))
    (directory / "000001" / "Image_heatmap_0.png").unlink()
    with pytest.raises(InputError, match=r"000001: 2 sensor poses but image\(s\) Image_heatmap_0\.png missing"):
        list(iter_sequence_dir(directory))


def test_bad_arrays_are_refused(tmp_path):
    T, images, _ = sequence()
    with pytest.raises(InputError, match=r"images: expected uint8 of shape \(3, 2, 320, 240, 3\)"):
        write_sequence_dir(tmp_path / "a", T, images[:, :, :240])
    with pytest.raises(InputError, match=r"stamps must be \(3,\) finite, strictly increasing"):
        write_sequence_dir(tmp_path / "b", T, images, stamps=[0.0, 0.0, 1.0])
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_frame_numbers_that_skip_are_a_warning_naming_them(tmp_path):
    from tactile6d.data.sequence_dirs import SequenceGapWarning

    T, images, _ = sequence(n_frames=8, n_sensors=1)
    directory = write_sequence_dir(tmp_path / "seq", T, images)
    for k in (2, 3, 4, 6):
        for f in (directory / f"{k:06d}").iterdir():
            f.unlink()
        (directory / f"{k:06d}").rmdir()
    with pytest.warns(SequenceGapWarning, match=r"seq: frame folders 000002-000004, 000006 missing \(4 frames\)"):
        frames = list(iter_sequence_dir(directory))
    assert [f[0] for f in frames] == [0, 1, 5, 7]
