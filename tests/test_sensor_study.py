"""Stage sensor_study on one scene of the box primitive with a tiny autoencoder: every L = 1, 2, 3."""

import json

import numpy as np
import pytest

from stages import prepare_object, sample_surface, sensor_study
from tactile6d import layout
from tactile6d.geometry import make_pose, rotvec_to_rotmat
from tactile6d.io import read_artifact, write_artifact
from tactile6d.sensor import contact_normals, contact_points, sensor_poses_touching
from test_estimator import write_tiny_autoencoder


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory, data_dir):
    root = tmp_path_factory.mktemp("artifacts")
    common = ["--object", "prim_box", f"paths.artifacts_dir={root}"]
    assert prepare_object.main(common + ["prepare.collision=hull", "prepare.n_metric_points=200"]) == 0
    assert sample_surface.main(common + ["sample.M=300"]) == 0
    write_tiny_autoencoder(root, 300, "prim_box")
    surface = read_artifact(layout.surface_file(root, "prim_box"), "surface")
    picks = [0, 100, 200]
    T_true = make_pose(rotvec_to_rotmat([0.2, 0.5, -0.4]), [0.1, 0.0, 0.2])
    sensors = T_true @ sensor_poses_touching(surface["points"][picks], surface["normals"][picks], 0.0, 0.002)
    write_artifact(layout.scenes_file(root, "tiny"), "scenes", {
        "names": np.array(["prim_box/scene_0"]), "objects": np.array(["prim_box"]), "T_world_object": T_true[None],
        "T_world_sensors": sensors[None], "images": np.full((1, 3, 320, 240, 3), 120, np.uint8),
        "contact_points": contact_points(sensors)[None], "contact_normals": contact_normals(sensors)[None],
        "contact_types": np.zeros((1, 3), int)})
    return root


def test_every_sensor_count_and_method_is_reported(artifacts, data_dir, monkeypatch):
    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    assert sensor_study.main(["--scene-set", "tiny", f"paths.artifacts_dir={artifacts}", "select.N=200"]) == 0
    results = json.loads(layout.metrics_file(artifacts, "sensor_count_tiny").read_text())
    assert set(results) == {"ours", "baseline"}
    for method in results:
        assert set(results[method]) == {"L1", "L2", "L3"}
        for summary in results[method].values():
            assert 0 <= summary["contact_acc_top1"] <= 100
    # with all three sensors on exact database points, the baseline finds the pose
    assert results["baseline"]["L3"]["pos_err_cm_top1"] < 0.5
    csv = (artifacts / "plots" / "sensor_count_tiny.csv").read_text().splitlines()
    assert csv[0].startswith("L,ours_pos_err_cm_top1") and len(csv) == 4
