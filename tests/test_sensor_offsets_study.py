"""scripts/sensor_offsets_study.py: the hand errors it draws and how it measures what they do to the gel."""

import numpy as np
import pytest

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from script_loader import load_script

study = load_script("sensor_offsets_study")


def test_errors_are_drawn_per_axis_in_the_sensors_frame():
    errors = study.draw_errors((4000, 3), 0.0015, np.radians(1.5), np.random.default_rng(0))
    assert errors.shape == (4000, 3, 4, 4)
    assert np.std(errors[..., :3, 3]) == pytest.approx(0.0015, rel=0.05)
    assert np.allclose(errors[..., 3, :], [0, 0, 0, 1])


def test_the_gel_shift_splits_along_the_axis_and_sideways():
    along = make_pose(np.eye(3), [0.001, 0.0, 0.0])  # 1 mm along the sensor's axis
    sideways = make_pose(np.eye(3), [0.0, 0.0006, 0.0008])  # 1 mm across it
    # a turn of 0.01 rad about z carries the gel centre (22 mm along x) 0.22 mm along y
    turn = make_pose(rotvec_to_rotmat(np.array([0.0, 0.0, 0.01])), np.zeros(3))
    errors = np.stack([along, sideways, turn])
    axial, side = study.axial_and_sideways_mm(errors)
    np.testing.assert_allclose(axial, [1.0, 0.0, 0.0], atol=2e-3)
    np.testing.assert_allclose(side, [0.0, 1.0, 0.22], atol=2e-3)
    np.testing.assert_allclose(study.gel_shift_mm(errors), np.hypot(axial, side))


def test_the_summary_counts_estimates_a_centimetre_or_more_off():
    assert study.summary([0.5, 1.0, 3.0]) == "1.50 (1.00) cm, 2 of 3 over 1 cm"


def test_the_calibration_grasps_are_written_as_scene_folders(tmp_path):
    from types import SimpleNamespace

    from tactile6d.core.geometry import line_to_pose
    from tactile6d.data.hdf5 import read_scene_dir

    rng = np.random.default_rng(0)
    true = make_pose(rotvec_to_rotmat(rng.normal(0, 1, (2, 3, 3)).reshape(-1, 3)), rng.normal(0, 0.1, (6, 3))).reshape(2, 3, 4, 4)
    cal = {"objects": np.array(["a", "b"]), "T_world_sensors": true,
           "T_world_object": make_pose(np.eye(3)[None].repeat(2, 0), np.array([[0.1, 0, 0.2], [0.0, 0.1, 0.2]])),
           "images": rng.integers(0, 255, (2, 3, 320, 240, 3), dtype=np.uint8)}
    bias = study.draw_errors((3,), 0.0015, np.radians(1.5), rng)
    args = SimpleNamespace(jitter_mm=0.0, jitter_deg=0.0)
    folders = study.write_grasps(cal, 2, bias, args, rng, tmp_path)
    assert [f.relative_to(tmp_path).as_posix() for f in folders] == ["a/grasp_0", "b/grasp_1"]
    for s, folder in enumerate(folders):
        T, images = read_scene_dir(folder)
        np.testing.assert_allclose(T, true[s] @ bias, atol=1e-12)  # as the hand reports them
        np.testing.assert_array_equal(images, cal["images"][s])
        np.testing.assert_allclose(line_to_pose((folder / "object_pose.txt").read_text()), cal["T_world_object"][s],
                                   atol=1e-12)
