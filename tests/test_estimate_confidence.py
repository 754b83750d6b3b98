"""The calibrated confidence in the online estimator and ``tactile6d estimate``: the estimate's
probability and distinct poses, their JSON form, and loading the model from the artifacts."""

import json
import shutil
import warnings
from dataclasses import replace

import numpy as np
import pytest
from test_estimate_cli import T_TRUE, artifacts, run, scene  # noqa: F401  (fixtures: prim_box artifacts, a triplet folder)
from test_estimator import make_estimator, world, write_object_artifacts  # noqa: F401  (world: a fixture)

from stages import calibrate_confidence
from tactile6d.core import geometry as g
from tactile6d.core import metrics
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_scene_dir, write_artifact
from tactile6d.estimation import confidence, disambiguation
from tactile6d.estimation import estimator as est
from tactile6d.perception.inputs import UnderdeterminedPoseWarning
from tactile6d.sim.scenes import SceneSet


def hand_model(ambiguity_ratio: float = 0.5) -> confidence.ConfidenceModel:
    """A model that trusts a large rival gap and a small spread, on unit-scaled features."""
    return confidence.ConfidenceModel(confidence.FEATURES, (2.0, -0.5), 0.5, (0.0, 1.0), (1.0, 2.0), ambiguity_ratio)


def with_model(estimator: est.Estimator, model: confidence.ConfidenceModel | None) -> est.Estimator:
    """The same estimator, built again with ``model``: through the constructor's keyword, as a user would."""
    return est.Estimator(estimator.points, estimator.penetration_model.pieces, estimator.db_angles, estimator.encoder,
                         estimator.settings, estimator.normals, estimator.surface, confidence_model=model)


def estimate_with(world, model, n_sensors: int = 3) -> tuple[est.Estimator, est.Estimate]:
    e = with_model(make_estimator(world, angles=world["db_angles"][world["idx"]][:n_sensors]), model)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnderdeterminedPoseWarning)  # one sensor: expected, tested elsewhere
        return e, e.estimate(world["T_world_sensors"][:n_sensors], world["images"][:n_sensors])


@pytest.mark.slow
def test_an_estimate_carries_the_models_confidence_and_distinct_poses(world):
    model = hand_model()
    e, result = estimate_with(world, model)
    assert e.spread_points.shape == (len(e.points[::2]), 3)  # 800 database points, every 2nd
    assert isinstance(result.confidence, float) and 0.0 <= result.confidence <= 1.0
    assert result.distinct[0] == 0 and result.distinct.dtype == np.int64
    # the probability of the ranked poses' own features, measured on the database points
    distances = metrics.adi(e.spread_points, result.poses, result.best)
    expected = model.probability(confidence.features(result.scores, distances))
    assert result.confidence == pytest.approx(float(expected), abs=1e-12)
    # three sensors on three faces determine the pose: no far pose scores nearly as well
    assert not result.ambiguous and result.distinct.tolist() == [0]
    # with_settings keeps the model
    assert e.with_settings(e.settings).confidence_model is model


@pytest.mark.slow
def test_without_a_model_there_is_no_confidence(world):
    _, result = estimate_with(world, None)
    assert result.confidence is None and result.distinct is None and result.ambiguous is False
    out = result.to_dict()
    assert out["confidence"] is None and out["ambiguous"] is False and out["distinct_poses"] == []


@pytest.mark.slow
def test_one_sensor_leaves_far_poses_scoring_nearly_as_well_ambiguous(world):
    ratio = 0.5
    e, result = estimate_with(world, hand_model(ratio), n_sensors=1)
    assert result.ambiguous and result.distinct[0] == 0 and len(result.distinct) >= 2
    # every listed rival is farther than RIVAL_DISTANCE from the best and within ``ratio`` of its score; no other is
    distances = metrics.adi(e.spread_points, result.poses, result.best)
    gaps = (result.scores - result.scores[0]) / result.scores[0]
    rivals = np.flatnonzero((distances > confidence.RIVAL_DISTANCE) & (gaps <= ratio))
    assert result.distinct[1:].tolist() == rivals.tolist()
    # a stricter model finds fewer (or no) rivals among the same poses
    _, strict = estimate_with(world, hand_model(ratio / 100), n_sensors=1)
    assert len(strict.distinct) < len(result.distinct)


@pytest.mark.slow
def test_ambiguous_is_more_than_one_distinct_pose(world):
    _, result = estimate_with(world, None)
    assert replace(result, distinct=np.array([0, 2])).ambiguous
    assert not replace(result, distinct=np.array([0])).ambiguous


@pytest.mark.slow
def test_to_dict_carries_the_confidence_and_is_json(world):
    _, result = estimate_with(world, hand_model())
    result = replace(result, distinct=np.array([0, 2], dtype=np.int64))  # as if rank 2 were a rival
    out = json.loads(json.dumps(result.to_dict()))
    assert out["confidence"] == pytest.approx(result.confidence) and out["ambiguous"] is True
    assert [d["rank"] for d in out["distinct_poses"]] == [0, 2]
    np.testing.assert_allclose(out["distinct_poses"][1]["pose"], result.poses[2])
    assert out["distinct_poses"][1]["score"] == pytest.approx(result.scores[2])


BASELINE = compose_config(["select.method=baseline", "select.contacts=landmark", "rank.agreement_weight=0"])


def test_from_artifacts_loads_the_model_when_there(tmp_path, world):
    write_object_artifacts(tmp_path, "prim_x", world["mesh"], world["points"], world["normals"])
    assert est.Estimator.from_artifacts("prim_x", tmp_path, BASELINE).confidence_model is None
    model = hand_model(0.3)
    path = layout.confidence_model_file(tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text(model.to_json())
    e = est.Estimator.from_artifacts("prim_x", tmp_path, BASELINE)
    assert e.confidence_model == model
    result = e.estimate(world["T_world_sensors"])
    assert 0.0 <= result.confidence <= 1.0 and result.distinct[0] == 0


@pytest.mark.parametrize("text", [
    json.dumps({**json.loads(hand_model().to_json()), "features": ["rival_gap", "best_score"]}),
    "{not json",
    json.dumps({"features": list(confidence.FEATURES)}),  # the rest missing
])
def test_a_model_the_code_cannot_use_names_the_stage(tmp_path, world, text):
    write_object_artifacts(tmp_path, "prim_x", world["mesh"], world["points"], world["normals"])
    path = layout.confidence_model_file(tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text(text)
    with pytest.raises(ArtifactError) as bad:
        est.Estimator.from_artifacts("prim_x", tmp_path, BASELINE)
    assert str(path) in str(bad.value) and "`dvc repro calibrate_confidence`" in str(bad.value)


# --- the command ---------------------------------------------------------------------------------------


@pytest.fixture
def artifacts_with_model(artifacts, tmp_path):  # noqa: F811  (the imported fixture)
    """A copy of prim_box's artifacts with a confidence model that calls every rival a second explanation."""
    root = tmp_path / "artifacts"
    shutil.copytree(artifacts, root)
    layout.confidence_model_file(root).parent.mkdir(parents=True)
    layout.confidence_model_file(root).write_text(hand_model(1e9).to_json())
    return root


ESTIMATE = ["--object", "prim_box", "select.method=baseline", "select.N=1000"]


@pytest.mark.slow
def test_the_command_prints_the_confidence_and_the_rivals(capsys, artifacts_with_model, scene):  # noqa: F811
    code, out, err = run(capsys, *ESTIMATE, "--scene", str(scene), "--artifacts", str(artifacts_with_model), "--json")
    assert code == 0, err
    result = json.loads(out)
    assert 0.0 <= result["confidence"] <= 1.0 and result["distinct_poses"][0]["rank"] == 0
    ranks = [d["rank"] for d in result["distinct_poses"]]
    code, out, err = run(capsys, *ESTIMATE, "--scene", str(scene), "--artifacts", str(artifacts_with_model))
    assert code == 0, err
    lines = out.splitlines()
    assert f"confidence {result['confidence']:.2f} (P that the best pose is within 1 cm ADI)" in lines
    # the model takes any pose over RIVAL_DISTANCE (ADI) from the best for a rival, and the box's top 5 hold some
    assert result["ambiguous"] and len(ranks) >= 2
    ambiguous = [line for line in lines if line.startswith("ambiguous:")]
    assert len(ambiguous) == 1 and f"{len(ranks)} distinct poses (ranks {', '.join(map(str, ranks))};" in ambiguous[0]


@pytest.mark.slow
def test_the_command_suggests_one_more_touch(capsys, artifacts_with_model, scene):  # noqa: F811
    """``--suggest-touch``: an ambiguous estimate's touch (disambiguation.touch_to_tell_apart on its distinct poses
    and the sensors given) in the JSON and as a ``touch:`` line; ``touch`` null where the estimate is not
    ambiguous (no model: never)."""
    code, out, err = run(capsys, *ESTIMATE, "--scene", str(scene), "--artifacts", str(artifacts_with_model), "--json",
                         "--suggest-touch")
    assert code == 0, err
    result = json.loads(out)
    assert result["ambiguous"]
    touch = result["touch"]
    assert touch is not None and set(touch) == {"point", "normal", "T_world_sensor", "separation", "tells_apart"}
    assert np.linalg.norm(touch["normal"]) == pytest.approx(1.0) and touch["separation"] > 0
    poses = np.array([d["pose"] for d in result["distinct_poses"]])
    T, _ = read_scene_dir(scene)
    box = est.Estimator.from_artifacts("prim_box", artifacts_with_model, compose_config(["select.method=baseline"]))
    expected = disambiguation.touch_to_tell_apart(box.surface, poses, T)
    np.testing.assert_allclose(touch["point"], expected.point, atol=1e-12)
    assert touch["tells_apart"] is expected.tells_apart
    code, out, err = run(capsys, *ESTIMATE, "--scene", str(scene), "--artifacts", str(artifacts_with_model),
                         "--suggest-touch")
    assert code == 0, err
    lines = [line for line in out.splitlines() if line.startswith("touch:")]
    assert len(lines) == 1 and " ".join(f"{v:.4f}" for v in expected.point) in lines[0]


def test_the_touch_line_says_whether_the_touch_tells_the_poses_apart():
    """The ``touch:`` line claims that a touch tells the poses apart only where it does (``Touch.tells_apart``);
    the fallback, the flattest reachable spot, says it pins the pose better; no touch at all says so."""
    from tactile6d.cli.estimate import touch_json, touch_line

    T = g.make_pose(np.eye(3), [0.1, 0.0, 0.0])
    telling = disambiguation.Touch(np.array([0.1, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), T, 0.012, True)
    fallback = telling._replace(separation=0.001, tells_apart=False)
    assert "tells the poses apart (their surfaces 1.2 cm apart there)" in touch_line(telling)
    line = touch_line(fallback)
    assert "pins the pose better but barely tells the poses apart (their surfaces 0.1 cm apart there" in line
    assert "0.1000 0.0000 0.0000" in line and "1.000 0.000 0.000" in line
    assert touch_line(None) == "touch: none reachable that tells the poses apart"
    assert touch_json(fallback)["tells_apart"] is False and touch_json(telling)["tells_apart"] is True
    assert touch_json(None) is None


@pytest.mark.slow
def test_the_command_without_a_model_says_so_in_one_line(capsys, artifacts, scene):  # noqa: F811
    code, out, err = run(capsys, *ESTIMATE, "--scene", str(scene), "--artifacts", str(artifacts))
    assert code == 0, err
    assert [line for line in out.splitlines() if "confidence" in line] == [
        "confidence: none (no confidence model; `dvc repro calibrate_confidence` makes it)"]
    code, out, err = run(capsys, *ESTIMATE, "--scene", str(scene), "--artifacts", str(artifacts), "--json")
    result = json.loads(out)
    assert result["confidence"] is None and result["ambiguous"] is False and result["distinct_poses"] == []
    assert "touch" not in result  # only with --suggest-touch
    code, out, err = run(capsys, *ESTIMATE, "--scene", str(scene), "--artifacts", str(artifacts), "--json",
                         "--suggest-touch")
    assert json.loads(out)["touch"] is None


@pytest.mark.slow
def test_the_stage_fits_the_same_model_in_one_process_and_on_two_workers(artifacts, scene):  # noqa: F811
    # Four scenes of the triplet, two of them labelled 3 cm off their truth: two right, two wrong estimates.
    T, images = read_scene_dir(scene)
    truth = np.stack([T_TRUE, T_TRUE @ g.make_pose(np.eye(3), [0.03, 0.0, 0.0])] * 2)
    write_artifact(layout.scenes_file(artifacts, "confidence"), "scenes", SceneSet(
        names=np.array(["r0", "w0", "r1", "w1"]), objects=np.array(["prim_box"] * 4), T_world_object=truth,
        T_world_sensors=np.stack([T] * 4), images=np.stack([images] * 4), contact_points=np.zeros((4, 3, 3)),
        contact_normals=np.zeros((4, 3, 3)), contact_types=np.zeros((4, 3), dtype=np.int64)).as_datasets())
    outputs = []
    for workers in (1, 2):
        assert calibrate_confidence.main([f"paths.artifacts_dir={artifacts}", "select.method=baseline", "select.N=400",
                                          f"executor.workers={workers}"]) == 0
        outputs.append([(layout.confidence_model_file(artifacts).parent / f).read_text() for f in ("model.json", "fit.json")]
                       + [layout.metrics_file(artifacts, "confidence").read_text()])
    assert outputs[0] == outputs[1]
    fit = json.loads(outputs[0][1])
    assert {n: fit[n]["adi_m"] < confidence.SUCCESS_ADI for n in fit} == {"r0": True, "w0": False, "r1": True, "w1": False}
