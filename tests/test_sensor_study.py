"""Stages sensor_study and ablation on one scene of the box primitive with a tiny autoencoder: every L = 1, 2, 3."""

import json

import numpy as np
import pytest
from omegaconf import OmegaConf
from test_estimator import apart_sensor_poses, write_tiny_autoencoder

from stages import ablation, prepare_object, sample_surface, sensor_study
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError
from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.core.sensor import contact_normals, contact_points
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.evaluation.sensor_subsets import sensor_subsets


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory, data_dir):
    root = tmp_path_factory.mktemp("artifacts")
    common = ["--object", "prim_box", f"paths.artifacts_dir={root}"]
    assert prepare_object.main(common + ["prepare.collision=hull", "prepare.n_metric_points=200"]) == 0
    assert sample_surface.main(common + ["sample.M=300"]) == 0
    write_tiny_autoencoder(root, 300, "prim_box")
    surface = read_artifact(layout.surface_file(root, "prim_box"), "surface")
    T_true = make_pose(rotvec_to_rotmat([0.2, 0.5, -0.4]), [0.1, 0.0, 0.2])
    sensors = T_true @ apart_sensor_poses(surface, 0)
    write_artifact(layout.scenes_file(root, "tiny"), "scenes", {
        "names": np.array(["prim_box/scene_0"]), "objects": np.array(["prim_box"]), "T_world_object": T_true[None],
        "T_world_sensors": sensors[None], "images": np.full((1, 3, 320, 240, 3), (97, 105, 100), np.uint8),
        "contact_points": contact_points(sensors)[None], "contact_normals": contact_normals(sensors)[None],
        "contact_types": np.zeros((1, 3), int)})
    return root


@pytest.mark.slow
def test_every_sensor_count_and_method_is_reported(artifacts, data_dir, monkeypatch):
    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    # in this process (1), then spread over 2 worker processes (the default): the same figures
    runs = {}
    for workers in (1, 2):
        assert sensor_study.main(["--scene-set", "tiny", f"paths.artifacts_dir={artifacts}", "select.N=200",
                                  f"evaluate.workers={workers}"]) == 0
        runs[workers] = layout.metrics_file(artifacts, "sensor_count_tiny").read_text()
    assert runs[1] == runs[2]
    results = json.loads(runs[2])
    assert set(results) == {"ours", "baseline"}
    for method in results:
        assert set(results[method]) == {"L1", "L2", "L3"}
        for summary in results[method].values():
            assert 0 <= summary["contact_acc_top1"] <= 100
    # with all three sensors on exact database points, the baseline finds the pose
    assert results["baseline"]["L3"]["pos_err_cm_top1"] < 0.5
    csv = (artifacts / "plots" / "sensor_count_tiny.csv").read_text().splitlines()
    assert csv[0].startswith("L,ours_pos_err_cm_top1") and len(csv) == 4


def test_sensor_subsets():
    assert sensor_subsets(3, 1) == [(0,), (1,), (2,)]
    assert sensor_subsets(3, 2) == [(0, 1), (0, 2), (1, 2)]
    assert sensor_subsets(4, 4) == [(0, 1, 2, 3)]
    with pytest.raises(ValueError):
        sensor_subsets(3, 4)


@pytest.mark.slow
def test_ablation_reports_each_variant_at_its_sensor_counts_and_sets(artifacts, data_dir, monkeypatch, tmp_path):
    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    # delta_h = pi: every database point passes the tiny autoencoder's angles, as for the baseline
    # landmark contacts: the scene's sensors touch exact database points at their landmarks
    cfg = compose_config([f"paths.artifacts_dir={artifacts}", "select.N=200", "select.delta_h=3.2",
                          "select.delta_h_max=3.2", "select.contacts=landmark"])
    OmegaConf.set_struct(cfg, False)
    paper = {"select": {"delta_d_rule": "paper"}, "rank": {"refine": False}}
    cfg.ablation.variants = {"paper": paper,
                             "normals": {"select": {"normal_tol_deg": 20.0}, "optimize": {"normal_weight": 0.01}},
                             "paper_again": {"rank": {"refine": False}, "select": {"delta_d_rule": "paper"}},
                             "elsewhere": {"select": {"N": 100}}}
    cfg.ablation.curves = ["paper"]
    cfg.ablation.curves_on = ["tiny"]
    cfg.ablation.only_on = {"elsewhere": ["validation"], "normals": ["tiny", "validation"]}
    cfg.ablation.variants_on = {"validation": ["paper"]}
    OmegaConf.save(cfg, tmp_path / "params.yaml")
    assert ablation.main(["--scene-set", "tiny", "--params", str(tmp_path / "params.yaml")]) == 0
    results = json.loads(layout.metrics_file(artifacts, "ablation_tiny").read_text())
    assert set(results) == {"paper", "normals", "paper_again"}  # "elsewhere" runs on validation only
    assert set(results["paper"]) == {"L1", "L2", "L3"}  # a curve: every sensor count
    assert set(results["normals"]) == set(results["paper_again"]) == {"L3"}  # the others: the scene's own L
    # the same settings give the same figures; they share one estimate where they are also made at the same
    # sensor counts (estimator_settings_key; here paper's are 1-3, paper_again's 3: two estimates, two timings)
    strip = lambda summary: {k: v for k, v in summary.items() if k != "time_s_median"}  # noqa: E731
    assert strip(results["paper_again"]["L3"]) == strip(results["paper"]["L3"])
    for variant in results.values():
        for summary in variant.values():
            assert {"pos_err_cm_top1", "adi_auc_rot_top1", "contact_acc_top1", "time_s_median"} <= set(summary)
            assert summary["time_s_median"] > 0
    # three sensors on exact database points (the normal switches apply up to two sensors by default): found
    assert results["normals"]["L3"]["pos_err_cm_top1"] < 0.5


def test_ablation_names_of_curves_and_sets_must_be_variants():
    with pytest.raises(ConfigError, match=r"ablation.curves .*\['nope'\]"):
        ablation.sensor_counts(["paper", "default"], 3, ["nope"], ["paper", "default"])
    with pytest.raises(ConfigError, match=r"ablation.only_on or ablation.variants_on .*\[.nope.\]"):
        ablation.variants_on("tiny", ["paper"], {"nope": ["tiny"]})
    assert ablation.variants_on("offaxis", ["paper", "default"], {"paper": ["caddeo2023"]}) == ["default"]
    # ablation.variants_on: a listed set runs its variants only, both filters apply, names are checked
    names = ["paper", "paper_fast", "default"]
    assert ablation.variants_on("variation", names, {}, {"variation": ["paper_fast", "default"]}) == ["paper_fast", "default"]
    assert ablation.variants_on("validation", names, {}, {"variation": ["default"]}) == names
    assert ablation.variants_on("variation", names, {"default": ["caddeo2023"]}, {"variation": ["default"]}) == []
    with pytest.raises(ConfigError, match=r"ablation.variants_on .*\['nope'\]"):
        ablation.variants_on("variation", names, {}, {"variation": ["nope"]})
    assert ablation.sensor_counts(["paper", "default"], 3, ["paper"], ["paper", "default"]) == {"paper": (1, 2, 3),
                                                                                               "default": (3,)}
    # a curve whose variant does not run on this set (ablation.only_on) is no error there
    assert ablation.sensor_counts(["default"], 3, ["paper"], ["paper", "default"]) == {"default": (3,)}


