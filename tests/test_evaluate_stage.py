"""Stage evaluate on fabricated scenes and ranked poses with known errors."""

import json
import warnings

import numpy as np
import pytest
import trimesh

from stages import evaluate
from tactile6d.core.geometry import make_pose
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.estimation import confidence
from tactile6d.estimation.run_storage import stack_contacts
from tactile6d.perception.contacts import sensors_to_landmark_contacts
from tactile6d.sim.meshes import pack_pieces


@pytest.fixture()
def artifacts(tmp_path):
    mesh = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    points, _ = trimesh.sample.sample_surface(mesh, 400, seed=0)
    write_artifact(layout.object_file(tmp_path, "box"), "object",
                   {"vertices": mesh.vertices, "faces": mesh.faces, "metric_points": points,
                    **pack_pieces([(np.asarray(mesh.vertices), np.asarray(mesh.faces))])})
    surface, faces = trimesh.sample.sample_surface(mesh, 300, seed=1)
    write_artifact(layout.surface_file(tmp_path, "box"), "surface",
                   {"points": surface, "normals": mesh.face_normals[faces], "face_index": faces})
    # a confidence that falls with the spread of the ranked poses (cm) only
    layout.confidence_model_file(tmp_path).parent.mkdir(parents=True)
    layout.confidence_model_file(tmp_path).write_text(confidence.ConfidenceModel(
        confidence.FEATURES, (0.0, -2.0), 0.0, (0.0, 0.0), (1.0, 1.0), 0.25).to_json())
    T_gt = np.stack([make_pose(np.eye(3), [0.1, 0.0, 0.2 + 0.1 * s]) for s in range(2)])
    p = np.array([[0.0, 0.0, 0.025], [0.06, 0.0, 0.0], [0.0, -0.04, 0.0]])
    n = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    sensors = np.stack([T @ sensor_poses_touching(p, n, 0.0, 0.0018) for T in T_gt])
    names = np.array(["box/scene_0", "box/scene_1"])
    write_artifact(layout.scenes_file(tmp_path, "tiny"), "scenes", {
        "names": names, "objects": np.array(["box", "box"]), "T_world_object": T_gt, "T_world_sensors": sensors,
        "images": np.zeros((2, 3, 320, 240, 3), np.uint8), "contact_points": np.zeros((2, 3, 3)),
        "contact_normals": np.zeros((2, 3, 3)), "contact_types": np.zeros((2, 3), int)})
    shift = make_pose(np.eye(3), [0.0, 0.03, 0.0])
    # ours: the true pose, then a pose 1 cm below it (the top sensor no longer pressed)
    below = make_pose(np.eye(3), [0.0, 0.0, -0.01])
    for method, offsets in (("ours", (np.eye(4), below)), ("baseline", (shift, shift))):
        poses = np.full((2, 5, 4, 4), np.nan)
        poses[:, :2] = np.stack([T_gt @ offsets[0], T_gt @ offsets[1]], axis=1)
        write_artifact(layout.run_dir(tmp_path, "tiny", method) / "ranked.h5", "ranked", {
            "names": names, "objects": np.array(["box", "box"]), "T_world_sensors": sensors,
            "failure": np.array(["", ""]), "poses": poses, "scores": np.zeros((2, 5)), "losses": np.zeros((2, 5)),
            "penetrations": np.zeros((2, 5, 3)), "n_poses": np.array([2, 2]),
            "seconds_encode": np.array([0.1, 0.3]), "seconds_select": np.array([0.1, 0.1]),
            "seconds_optimize": np.array([0.2, 0.2]), "seconds_rank": np.array([0.1, 0.1]),
            **stack_contacts([sensors_to_landmark_contacts(T) for T in sensors], 3)})
    return tmp_path


@pytest.mark.slow
def test_metrics_file_has_the_keys_and_the_values(artifacts):
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*does not press")  # every sensor is pressed at the true poses
        assert evaluate.main(["--scene-set", "tiny", f"paths.artifacts_dir={artifacts}"]) == 0
    m = json.loads(layout.metrics_file(artifacts, "tiny").read_text())
    assert set(m) == {"ours", "baseline"}
    for key in ("pos_err_cm_top1", "pos_err_cm_top5", "adi_auc_paper_top1", "adi_auc_std_top1",
                "adi_auc_rot_top1", "contact_acc_top1", "contact_acc_top5", "contact_acc_image_top1",
                "contact_acc_image_top5", "time_s_median", "n_scenes"):
        assert key in m["ours"] and key in m["baseline"]
    assert m["ours"]["pos_err_cm_top1"] == 0 and m["ours"]["contact_acc_top1"] == 100
    assert m["ours"]["adi_auc_paper_top1"] == 100
    # image-consistent: the true pose of each scene yes, the pose 1 cm below no, the 3 missing ones no
    assert m["ours"]["contact_acc_image_top1"] == 100
    assert m["ours"]["contact_acc_image_top5"] == pytest.approx(20)
    assert m["ours"]["contact_acc_top5"] == pytest.approx(20)
    assert m["baseline"]["contact_acc_image_top1"] == 0
    assert m["baseline"]["pos_err_cm_top1"] == pytest.approx(3.0)
    assert m["baseline"]["contact_acc_top1"] == 0  # 3 cm off: the sensors no longer touch
    assert m["ours"]["time_s_median"] == pytest.approx(0.6)  # 0.5 and 0.7 s per estimate
    assert m["ours"]["n_scenes"] == 2
    details = json.loads((artifacts / "eval" / "tiny.json").read_text())
    assert details["ours"]["per_scene"]["box/scene_0"]["contact_image_ok"][:2] == [1.0, 0.0]
    # ours' confidence: both scenes right, their #2 1 cm away (a rival, scoring the same: ambiguous)
    assert m["ours"]["n_wrong_adi1cm"] == 0 and np.isnan(m["ours"]["confidence_auroc_adi1cm"])
    assert m["ours"]["ambiguous_fraction"] == 1.0
    p = details["ours"]["confidence"]["per_scene"]["box/scene_0"]
    assert 0.0 < p < 0.5 and m["ours"]["confidence_brier"] == pytest.approx((1 - p) ** 2, rel=1e-6)
    assert "confidence_auroc_adi1cm" not in m["baseline"]
    table = (artifacts / "eval" / "tiny_table.md").read_text()
    assert "| box |" in table and "| **average** |" in table


def test_a_sensor_untouched_at_the_true_pose_is_reported(artifacts):
    path = layout.scenes_file(artifacts, "tiny")
    scenes = dict(read_artifact(path, "scenes").data)
    scenes["T_world_sensors"] = scenes["T_world_sensors"].copy()
    scenes["T_world_sensors"][1, 0, 2, 3] += 0.01  # scene 1: the top sensor lifted 1 cm off the box
    write_artifact(path, "scenes", scenes)
    with pytest.warns(UserWarning, match="1 scene.*box/scene_1"):
        assert evaluate.main(["--scene-set", "tiny", f"paths.artifacts_dir={artifacts}"]) == 0
    m = json.loads(layout.metrics_file(artifacts, "tiny").read_text())
    # scene 1's true pose leaves the lifted sensor untouched, and so does the estimate (the true pose)
    assert m["ours"]["contact_acc_image_top1"] == 100
