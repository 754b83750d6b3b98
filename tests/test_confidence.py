"""tactile6d.estimation.confidence against naive references, and the stage calibrate_confidence end to end."""

import json

import numpy as np
import pytest
from scipy.optimize import minimize
from test_identify import BOX_TOUCHES, T_TRUE, prim_artifacts, touching_sensors  # noqa: F401 (a fixture)

from tactile6d.core.geometry import make_pose
from tactile6d.data import layout
from tactile6d.data.hdf5 import write_artifact
from tactile6d.estimation import confidence
from tactile6d.sim.scenes import SceneSet


def test_sigmoid_is_the_logistic_function_without_overflow():
    z = np.linspace(-30, 30, 61)
    np.testing.assert_allclose(confidence.sigmoid(z), 1 / (1 + np.exp(-z)), rtol=1e-12)
    with np.errstate(over="raise"):
        assert confidence.sigmoid(np.array([-1e4, 1e4])).tolist() == [0.0, 1.0]


def test_the_newton_fit_is_the_penalised_likelihood_maximum():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 2))
    y = (rng.random(200) < 1 / (1 + np.exp(-(0.5 + 2 * x[:, 0] - x[:, 1])))).astype(float)
    ridge = 0.7
    weights, bias = confidence.fit_logistic(x, y, ridge)

    def objective(beta):  # the naive negative log-posterior, the bias unpenalised
        z = beta[0] + x @ beta[1:]
        return np.sum(np.logaddexp(0, z) - y * z) + 0.5 * ridge * np.sum(beta[1:] ** 2)

    reference = minimize(objective, np.zeros(3), method="BFGS", options={"gtol": 1e-10}).x
    np.testing.assert_allclose(np.r_[bias, weights], reference, atol=1e-5)
    assert weights[0] > 1 and weights[1] < 0  # the generating signs


def test_a_perfectly_separating_feature_keeps_finite_weights():
    x = np.array([[-2.0], [-1.0], [1.0], [2.0]])
    weights, bias = confidence.fit_logistic(x, np.array([0, 0, 1, 1.0]), ridge=1.0)
    assert np.isfinite(weights).all() and 0 < weights[0] < 20 and abs(bias) < 1e-9


def test_rivals_are_the_far_poses_and_their_gaps_are_relative():
    scores = np.array([2.0, 2.1, 3.0, 2.2])
    distances = np.array([0.0, 0.001, 0.02, 0.012])  # #1 is near the best: not a rival
    np.testing.assert_allclose(confidence.rival_gaps(scores, distances), [0.5, 0.1])
    x = confidence.features(scores, distances)
    np.testing.assert_allclose(x, [np.log10(0.1), 2.0])
    assert confidence.distinct_poses(scores, distances, 0.25).tolist() == [0, 3]
    assert confidence.distinct_poses(scores, distances, 0.05).tolist() == [0]
    # no rival at all: the gap is at its maximum, log10(10) = 1
    assert confidence.features(scores[:2], distances[:2])[0] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="without poses"):
        confidence.features(np.zeros(0), np.zeros(0))


def test_distances_from_the_best_are_adi_with_the_best_as_truth():
    rng = np.random.default_rng(1)
    points = rng.normal(scale=0.03, size=(300, 3))
    poses = np.stack([make_pose(np.eye(3), [0, 0, 0]), make_pose(np.eye(3), [0.02, 0, 0])])
    d = confidence.distances_from_best(points, poses)
    naive = np.mean([np.min(np.linalg.norm(points + [0.02, 0, 0] - p, axis=1)) for p in points])
    assert d[0] == 0 and d[1] == pytest.approx(naive)
    assert confidence.distances_from_best(points, np.zeros((0, 4, 4))).shape == (0,)


def test_spread_points_are_an_even_deterministic_subset():
    points = np.arange(3 * 1234, dtype=float).reshape(-1, 3)
    chosen = confidence.spread_points(points, 500)
    assert len(chosen) <= 500 and len(chosen) == len(points[::3])
    np.testing.assert_array_equal(chosen, points[::3])
    assert len(confidence.spread_points(points[:10], 500)) == 10


def test_reliability_bins_against_a_loop():
    rng = np.random.default_rng(2)
    p = rng.random(300)
    y = rng.random(300) < p
    bins = confidence.reliability(p, y, n_bins=4)
    assert sum(b["count"] for b in bins) == 300
    for b in bins:
        inside = (p >= b["low"]) & ((p < b["high"]) | (b["high"] == 1.0))
        assert b["count"] == inside.sum()
        assert b["predicted"] == pytest.approx(p[inside].mean()) and b["observed"] == pytest.approx(y[inside].mean())
    assert confidence.brier(np.array([1.0, 0.0]), np.array([True, True])) == 0.5
    assert np.isnan(confidence.auroc(np.array([0.2, 0.9]), np.array([True, True])))


def test_the_model_round_trips_and_refuses_other_features():
    model = confidence.fit_model(np.array([[0.0, 1.0], [1.0, 0.5], [0.5, 3.0], [0.2, 0.0]]),
                                 np.array([False, True, True, False]), ambiguity_ratio=0.3)
    again = confidence.ConfidenceModel.from_json(model.to_json())
    assert again == model
    x = np.array([[0.3, 1.0], [1.0, 0.0]])
    np.testing.assert_array_equal(again.probability(x), model.probability(x))
    raw = json.loads(model.to_json())
    raw["features"] = ["rival_gap"]
    with pytest.raises(ValueError, match="calibrate_confidence"):
        confidence.ConfidenceModel.from_json(json.dumps(raw))


@pytest.mark.slow
def test_the_stage_fits_on_its_scenes_and_the_estimator_then_reports_the_confidence(prim_artifacts, tmp_path):  # noqa: F811
    """Four box scenes estimated by the baseline: two whose truth is where the sensors touch (right) and
    two whose recorded truth is 3 cm away from it (wrong, as a mislabelled scene would be)."""
    import shutil

    from stages import calibrate_confidence
    from tactile6d.core.config import compose_config
    from tactile6d.estimation.estimator import Estimator

    artifacts = tmp_path / "artifacts"
    shutil.copytree(prim_artifacts, artifacts)
    box = touching_sensors(artifacts, "prim_box", BOX_TOUCHES)
    away = T_TRUE @ make_pose(np.eye(3), [0.03, 0.0, 0.0])
    scenes = SceneSet(
        names=np.array([f"prim_box/scene_{i}" for i in range(4)]), objects=np.array(["prim_box"] * 4),
        T_world_object=np.stack([T_TRUE, away, T_TRUE, away]), T_world_sensors=np.stack([box] * 4),
        images=np.zeros((4, 3, 320, 240, 3), np.uint8), contact_points=np.zeros((4, 3, 3)),
        contact_normals=np.zeros((4, 3, 3)), contact_types=np.zeros((4, 3), dtype=np.int64))
    write_artifact(layout.scenes_file(artifacts, "confidence"), "scenes", scenes.as_datasets())
    overrides = [f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box]", "select.method=baseline"]
    assert calibrate_confidence.main(overrides) == 0

    summary = json.loads(layout.metrics_file(artifacts, "confidence").read_text())
    assert summary["n_scenes"] == 4 and summary["n_right"] == 2
    fit = json.loads((artifacts / "confidence" / "fit.json").read_text())
    assert [v["adi_m"] < 0.01 for v in fit.values()] == [True, False, True, False]
    model = confidence.ConfidenceModel.from_json(layout.confidence_model_file(artifacts).read_text())
    assert model.features == confidence.FEATURES and model.ambiguity_ratio == 0.25
    # the same inputs, the same estimates: the online estimator's confidence is the stage's probability
    estimator = Estimator.from_artifacts("prim_box", artifacts, compose_config(overrides))
    estimate = estimator.estimate(box, np.zeros((3, 320, 240, 3), np.uint8))
    assert estimate.confidence == pytest.approx(fit["prim_box/scene_0"]["probability"])


@pytest.mark.slow
def test_the_stage_refuses_scenes_that_are_all_right_or_all_wrong(prim_artifacts, tmp_path):  # noqa: F811
    import shutil

    from stages import calibrate_confidence
    from tactile6d.core.errors import ConfigError

    artifacts = tmp_path / "artifacts"
    shutil.copytree(prim_artifacts, artifacts)
    box = touching_sensors(artifacts, "prim_box", BOX_TOUCHES)
    scenes = SceneSet(
        names=np.array(["prim_box/scene_0"]), objects=np.array(["prim_box"]), T_world_object=T_TRUE[None],
        T_world_sensors=box[None], images=np.zeros((1, 3, 320, 240, 3), np.uint8),
        contact_points=np.zeros((1, 3, 3)), contact_normals=np.zeros((1, 3, 3)),
        contact_types=np.zeros((1, 3), dtype=np.int64))
    write_artifact(layout.scenes_file(artifacts, "confidence"), "scenes", scenes.as_datasets())
    with pytest.raises(ConfigError, match="all right: nothing to calibrate on"):
        calibrate_confidence.main([f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box]",
                                   "select.method=baseline"])
