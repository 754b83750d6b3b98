import numpy as np
import pytest
import trimesh

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.evaluation import scoring
from tactile6d.sim import surface_sampling


@pytest.fixture(scope="module")
def box():
    mesh = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    points, _ = trimesh.sample.sample_surface(mesh, 500, seed=0)
    return mesh, surface_sampling.sample_surface(mesh), np.asarray(points)


def scene(T_gt):
    """Three sensors on the box's top face, an end face and a side face, in the world."""
    p = np.array([[0.0, 0.0, 0.025], [0.06, 0.0, 0.0], [0.0, -0.04, 0.0]])
    n = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    return T_gt @ sensor_poses_touching(p, n, 0.0, 0.0018)


def test_perfect_and_shifted_estimates(box):
    _mesh, surface, points = box
    T_gt = make_pose(np.eye(3), [0.1, 0.0, 0.2])
    sensors = scene(T_gt)
    shifted = T_gt @ make_pose(np.eye(3), [0.0, 0.0, 0.01])  # 1 cm off: a sensor now 1 cm inside
    ranked = np.stack([T_gt, shifted, T_gt, T_gt, T_gt])
    e = scoring.scene_errors(ranked, 5, T_gt, sensors, points, surface)
    np.testing.assert_allclose(e["position"], [0, 0.01, 0, 0, 0], atol=1e-12)
    assert e["contact_ok"].tolist() == [1, 0, 1, 1, 1]
    summary = scoring.summarise({k: v[None] for k, v in e.items()})
    assert summary["pos_err_cm_top1"] == 0 and summary["pos_err_cm_top5"] == pytest.approx(0.2)
    assert summary["adi_auc_paper_top1"] == 100 and summary["contact_acc_top1"] == 100
    assert summary["contact_acc_top5"] == pytest.approx(80)
    # the standard AUC of the shifted pose: ADI < 1 cm -> partial credit
    assert 80 < summary["adi_auc_std_top5"] < 100


def test_missing_estimates_count_as_failures(box):
    _mesh, surface, points = box
    T_gt = make_pose(np.eye(3), [0.1, 0.0, 0.2])
    sensors = scene(T_gt)
    good = scoring.scene_errors(np.stack([T_gt] * 5), 5, T_gt, sensors, points, surface)
    none = scoring.scene_errors(np.zeros((5, 4, 4)), 0, T_gt, sensors, points, surface)
    assert np.isnan(none["position"]).all()
    errors = {k: np.stack([good[k], none[k]]) for k in good}
    summary = scoring.summarise(errors)
    assert summary["pos_err_cm_top1"] == 0  # only the scene with an estimate has a position error
    assert summary["adi_auc_paper_top1"] == pytest.approx(50)
    assert summary["contact_acc_top1"] == pytest.approx(50)


def test_rotation_error_shows_in_rotation_auc_only_through_rotation(box):
    _mesh, surface, points = box
    T_gt = make_pose(np.eye(3), [0.1, 0.0, 0.2])
    rotated = make_pose(rotvec_to_rotmat([0, 0, 0.3]), [0.1, 0.0, 0.2])
    e = scoring.scene_errors(np.stack([rotated]), 1, T_gt, scene(T_gt), points, surface, k=1)
    assert e["position"][0] == 0 and e["adi_rotation"][0] == pytest.approx(e["adi"][0])
    assert e["adi"][0] > 0.005


def test_by_object_average_and_table(box):
    errors = {"position": np.array([[0.01], [0.03]]), "adi": np.array([[0.001], [0.05]]),
              "adi_rotation": np.array([[0.001], [0.05]]), "contact_ok": np.array([[1.0], [0.0]])}
    by_obj = scoring.summarise_by_object(errors, np.array(["a", "b"]))
    assert by_obj["average"]["pos_err_cm_top1"] == pytest.approx(2.0)
    assert by_obj["average"]["contact_acc_top1"] == pytest.approx(50)
    table = scoring.table_markdown({"ours": by_obj, "baseline": by_obj})
    assert table.splitlines()[0].startswith("| object | ours pos #1 (cm)")
    assert "| **average** | 2.00 |" in table


def test_ablation_table_has_a_row_per_variant_and_columns_per_sensor_count():
    row = {"pos_err_cm_top1": 1.234, "adi_auc_rot_top1": 95.0, "contact_acc_top1": 50.0, "time_s_median": 0.31}
    table = scoring.ablation_markdown({"paper": {"L1": row, "L2": row}, "default": {"L2": row}}).splitlines()
    assert table[0].startswith("| variant | L1 pos (cm) | L1 rot AUC | L1 contact | L1 s | L2 pos (cm)")
    assert table[2] == "| paper | 1.23 | 95.0 | 50.0 | 0.31 | 1.23 | 95.0 | 50.0 | 0.31 |"
    assert table[3] == "| default | nan | nan | nan | nan | 1.23 | 95.0 | 50.0 | 0.31 |"


def test_image_contact_accuracy_is_pooled_like_contact_accuracy():
    # two scenes: all five estimates consistent; the best inconsistent, then 2 of 4, and no fifth estimate
    image_ok = np.stack([np.ones(5), scoring.pad_to_k([0.0, 1.0, 0.0, 1.0])])
    np.testing.assert_array_equal(np.isnan(image_ok[1]), [False] * 4 + [True])
    errors = {"position": np.zeros((2, 5)), "adi": np.zeros((2, 5)), "adi_rotation": np.zeros((2, 5)),
              "contact_ok": np.ones((2, 5)), "contact_image_ok": image_ok}
    summary = scoring.summarise(errors)
    assert summary["contact_acc_image_top1"] == pytest.approx(50)
    assert summary["contact_acc_image_top5"] == pytest.approx(70)  # 7 of 10, the missing one a failure
    assert summary["contact_acc_top1"] == 100
    by_obj = scoring.summarise_by_object(errors, np.array(["a", "b"]))
    assert by_obj["average"]["contact_acc_image_top1"] == pytest.approx(50)
    # without the key (callers that do not compute it) the figures are simply absent
    del errors["contact_image_ok"]
    assert "contact_acc_image_top1" not in scoring.summarise_by_object(errors, np.array(["a", "b"]))["average"]
