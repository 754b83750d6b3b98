"""Identification: the calibrated score (against a plain reference), an identifier that tells a box from
a box of another size, bad libraries, and the ``tactile6d identify`` command's errors."""

import os

import numpy as np
import pytest
import trimesh

from tactile6d.cli import main as cli_main
from tactile6d.core import geometry as g
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, ConfigError, InputError
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.core.settings import Settings
from tactile6d.estimation import identity_model
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.identifier import Identifier, load_weights
from tactile6d.runtime.executor import Executor
from tactile6d.sim.surface_sampling import sample_surface_even

T_TRUE = g.make_pose(g.rotvec_to_rotmat(np.array([0.4, 0.9, -0.3])), [0.05, -0.02, 0.15])


# ---- the calibrated score -------------------------------------------------------------------------

def probabilities_by_hand(scores):
    """softmax(-s) written out, objects with an infinite score left out."""
    out = np.zeros(len(scores))
    finite = [i for i, s in enumerate(scores) if np.isfinite(s)]
    total = sum(np.exp(-scores[i]) for i in finite)
    for i in finite:
        out[i] = np.exp(-scores[i]) / total
    return out


@pytest.mark.parametrize("seed", range(4))
def test_probabilities_match_the_softmax_written_out(seed):
    rng = np.random.default_rng(seed)
    scores = rng.uniform(0, 20, 7)
    scores[rng.integers(7)] = np.inf
    np.testing.assert_allclose(identity_model.scores_to_probabilities(scores), probabilities_by_hand(scores),
                               rtol=1e-12, atol=1e-15)


def test_large_scores_do_not_underflow_and_nothing_matched_gives_zeros():
    p = identity_model.scores_to_probabilities(np.array([1000.0, 1001.0, np.inf]))
    np.testing.assert_allclose(p, [1 / (1 + np.exp(-1)), np.exp(-1) / (1 + np.exp(-1)), 0.0])
    assert identity_model.scores_to_probabilities(np.full(3, np.inf)).tolist() == [0.0, 0.0, 0.0]


def test_a_feature_row_with_nan_scores_infinite():
    f = np.array([[1.0, 2.0, 0.5], [np.nan, np.nan, np.nan]])
    s = identity_model.features_to_scores(f, np.array([1.0, 0.5, 2.0]))
    assert s[0] == pytest.approx(3.0) and s[1] == np.inf


def test_fitted_weights_recover_those_that_drew_the_labels():
    """Scenes whose true object is drawn from the conditional logit with known weights: the fit finds
    them back (within the sampling error of 3000 scenes)."""
    rng = np.random.default_rng(1)
    true_w = np.array([2.0, 0.5, 1.0])
    features = rng.uniform(0, 3, (3000, 6, 3))
    p = identity_model.scores_to_probabilities(identity_model.features_to_scores(features, true_w))
    truth = np.array([rng.choice(6, p=row) for row in p])
    w = identity_model.fit_weights(features, truth, l2=0.0)
    np.testing.assert_allclose(w, true_w, rtol=0.15)
    assert identity_model.negative_log_likelihood(w, features, truth) <= \
        identity_model.negative_log_likelihood(true_w, features, truth) + 1e-9


def test_fit_needs_labelled_scenes_of_the_right_shape():
    with pytest.raises(InputError, match="need features"):
        identity_model.fit_weights(np.zeros((4, 1, 3)), np.zeros(4, int))
    with pytest.raises(InputError, match="indices"):
        identity_model.fit_weights(np.zeros((4, 3, 3)), np.full(4, 3))


# ---- an identifier over two boxes of different widths -------------------------------------------

def box(width: float) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=[width, 0.06, 0.16])


class FaceAngleEncoder:
    """Stands in for the autoencoder: the 'latent' of a sensor's image is the angle of the face it
    touches, the same on both boxes (look-alikes to touch); ``identify`` encodes through it once."""

    def __init__(self, angles):
        self.true_angles = np.asarray(angles, dtype=float)
        self.calls = 0

    def latents(self, images):
        self.calls += 1
        return self.true_angles[: len(images), None]

    def angles(self, latents):
        return latents[:, 0]

    def __call__(self, images):
        return self.angles(self.latents(images))

    def encodes_like(self, other):
        return True


def face_angles(normals):
    """0.1 rad per face direction (+x, -x, +y, -y, +z, -z), the same for any box."""
    axis = np.abs(normals).argmax(axis=1)
    sign = np.sign(normals[np.arange(len(normals)), axis]) < 0
    return 0.1 * (2 * axis + sign)


def box_estimator(width, encoder, settings):
    mesh = box(width)
    points, normals, _ = sample_surface_even(mesh, 900, np.random.default_rng(0))
    return Estimator(points, [mesh.vertices], face_angles(normals), encoder, settings, normals, mesh)


@pytest.fixture(scope="module")
def squeezed():
    """Two sensors squeeze the 10 cm box across its width (+x and -x faces), a third touches -z."""
    mesh = box(0.10)
    points, normals, _ = sample_surface_even(mesh, 900, np.random.default_rng(0))
    targets = np.array([[0.05, 0.01, 0.02], [-0.05, -0.01, 0.03], [0.01, 0.0, -0.08]])
    idx = np.array([np.argmin(np.linalg.norm(points - t, axis=1)) for t in targets])
    T_object_sensors = sensor_poses_touching(points[idx], normals[idx], [0.2, -1.0, 2.0], 0.002)
    return T_TRUE @ T_object_sensors, face_angles(normals[idx])


def landmark_settings(**overrides):
    base = {"select.contacts": "landmark", "rank.agreement_weight": 0.0, **overrides}
    return Settings.from_cfg(compose_config([f"{k}={v}" for k, v in base.items()]))


SCREEN = {"N": 500, "delta_d_max": 0.01, "candidates": 10, "max_checks": None}


@pytest.mark.slow  # end-to-end identification: out of the quick subset
@pytest.mark.parametrize("method", ["ours", "baseline"])
def test_the_box_of_the_right_width_wins_over_wider_and_narrower_ones(squeezed, method):
    T_sensors, angles = squeezed
    encoder = FaceAngleEncoder(angles)
    images = np.zeros((3, 320, 240, 3), np.uint8)

    def identify(**overrides):
        settings = landmark_settings(**{"select.method": method, **overrides})
        library = {f"box_{round(w * 1000)}mm": box_estimator(w, encoder if method == "ours" else None, settings)
                   for w in (0.09, 0.10, 0.115)}
        return Identifier(library, weights=np.array([1.0, 1.0, 1.0]), screen=SCREEN).identify(T_sensors, images)

    # Sensor poses uncertain by a hand's kinematics (the default sigmas): the right width still wins; by how
    # much less than with exact poses is measured in docs/real_sensors.md.
    assert identify().best.name == "box_100mm"
    encoder.calls = 0
    # The squeeze's sensor poses are exact and declared so: the right width wins outright.
    result = identify(**{"sensors.pose_sigma_mm": 0, "sensors.pose_sigma_deg": 0})
    assert result.best.name == "box_100mm"
    assert result.best.probability > 0.9
    assert sum(o.probability for o in result.objects) == pytest.approx(1.0)
    assert result.refined  # the winner's pose is the full estimate's
    position_error = np.linalg.norm(result.best.pose[:3, 3] - T_TRUE[:3, 3])
    assert position_error < 0.005
    if method == "ours":
        assert encoder.calls == 1  # the images were encoded once for the three objects


class FinishingInOrder(Executor):
    """Screens in this process and hands the candidates back in ``order``, as workers that finished in
    that order would (``Executor.completed``)."""

    def __init__(self, identifier, order):
        self.identifier, self.order = identifier, order

    def completed(self, fn, sources, names, T_sensors, encodings, desc=None):
        found = [self.identifier.candidate(*args) for args in zip(names, T_sensors, encodings)]
        for i in self.order:
            yield i, found[i]

    def describe(self):
        return "in this process, in a chosen order"


@pytest.mark.slow  # end-to-end identification: out of the quick subset
@pytest.mark.parametrize("order, guess_wins", [([1, 0, 2], True), ([0, 2, 1], False)])
def test_the_guess_at_the_winner_changes_nothing(squeezed, monkeypatch, order, guess_wins):
    """A spread screen makes the full estimate of the object leading when one is left to screen. When the
    winner (box_100mm, index 1) is in by then, that estimate is the refinement; when it comes last, the
    guess is a wrong box and the winner is estimated after. Either way the same identity_model."""
    T_sensors, angles = squeezed
    settings = landmark_settings(**{"select.method": "ours"})
    library = {f"box_{round(w * 1000)}mm": box_estimator(w, FaceAngleEncoder(angles), settings)
               for w in (0.09, 0.10, 0.115)}
    images = np.zeros((3, 320, 240, 3), np.uint8)
    identifier = Identifier(library, weights=np.array([1.0, 1.0, 1.0]), screen=SCREEN)
    plain = identifier.identify(T_sensors, images)
    assert plain.best.name == "box_100mm" and all(o.candidate.matched for o in plain.objects)
    assert plain.seconds["guess"] == 0.0  # in one process there is nothing to overlap

    made = []
    full_estimate = Identifier._full_estimate
    monkeypatch.setattr(Identifier, "_full_estimate",
                        lambda self, name, *args: made.append(name) or full_estimate(self, name, *args))
    identifier.spread(FinishingInOrder(identifier, order), source=None)
    result = identifier.identify(T_sensors, images)
    if guess_wins:
        assert made == ["box_100mm"] and result.seconds["guess"] > 0
    else:
        assert len(made) == 2 and made[0] != "box_100mm" and made[1] == "box_100mm"
    assert result.refined == plain.refined
    assert [o.name for o in result.objects] == [o.name for o in plain.objects]
    for a, b in zip(plain.objects, result.objects):
        assert a.probability == b.probability
        np.testing.assert_array_equal(a.pose, b.pose)
    np.testing.assert_array_equal(result.best.candidate.estimate.poses, plain.best.candidate.estimate.poses)


@pytest.mark.slow
def test_an_identifier_without_weights_only_screens(squeezed):
    T_sensors, _ = squeezed
    settings = landmark_settings(**{"select.method": "baseline"})
    identifier = Identifier({"a": box_estimator(0.10, None, settings)}, screen=SCREEN)
    found, _ = identifier.candidates(T_sensors)
    assert found[0].matched and found[0].features.shape == (len(identity_model.FEATURES),)
    with pytest.raises(InputError, match="calibrated weights"):
        identifier.identify(T_sensors)


@pytest.mark.slow
def test_objects_with_other_settings_cannot_share_an_identifier():
    a = box_estimator(0.10, None, landmark_settings(**{"select.method": "baseline"}))
    b = box_estimator(0.10, None, landmark_settings(**{"select.method": "baseline", "select.N": 100}))
    with pytest.raises(InputError, match="other settings"):
        Identifier({"a": a, "b": b})


def test_objects_without_artifacts_are_named_in_one_error(tmp_path):
    with pytest.raises(ArtifactError) as info:
        Identifier.from_artifacts(["002_master_chef_can", "no_such_thing"], tmp_path)
    message = str(info.value)
    assert "2 of 2 objects" in message and "002_master_chef_can" in message and "no_such_thing" in message
    assert "dvc repro" in message


def test_a_distractor_without_artifacts_is_named_with_its_own_stage(tmp_path):
    with pytest.raises(ArtifactError) as info:
        Identifier.from_artifacts([], tmp_path, distractors=["shape_9"])
    assert "1 of 1 objects" in str(info.value) and "dvc repro sample_distractors`" in str(info.value)


def test_an_object_cannot_also_be_a_distractor(tmp_path):
    with pytest.raises(InputError, match="prim_box cannot be more than one of"):
        Identifier.from_artifacts(["prim_box"], tmp_path, distractors=["prim_box", "shape_1"])


@pytest.mark.slow
def test_the_command_names_unknown_objects_and_missing_scenes(tmp_path, capsys):
    assert cli_main(["identify", "--scene", str(tmp_path), "--objects", "no_such_thing",
                     "--artifacts", str(tmp_path)]) == 2
    assert "unknown object 'no_such_thing'" in capsys.readouterr().err
    assert cli_main(["identify", "--scene", str(tmp_path / "missing"), "--objects", "002_master_chef_can",
                     "--artifacts", str(tmp_path)]) == 2
    assert "error:" in capsys.readouterr().err
    # Known units are matched only where no no-contact image is passed: beside --background, an error.
    from tactile6d.data.hdf5 import write_tactile_image

    write_tactile_image(tmp_path / "unit_7.png", np.full((320, 240, 3), (90, 100, 95), np.uint8))
    assert cli_main(["identify", "--scene", str(tmp_path), "--objects", "002_master_chef_can",
                     "--artifacts", str(tmp_path), "--background", str(tmp_path / "unit_7.png"),
                     "--known-units", str(tmp_path / "unit_7.png")]) == 2
    assert "give --background or --known-units, not both" in capsys.readouterr().err


# ---- from artifacts, in this process and in worker processes -----------------------------------

@pytest.fixture(scope="module")
def prim_artifacts(tmp_path_factory):
    """prim_box's and prim_cylinder's object.h5 and surface.h5, made by the stages' own main(), and
    the same of the procedural distractor shape_3 (a 10 cm triangular prism) under distractors/."""
    from stages import prepare_object, sample_surface

    root = tmp_path_factory.mktemp("artifacts")
    for name, flags in (("prim_box", []), ("prim_cylinder", []), ("shape_3", ["--distractor"])):
        common = ["--object", name, *flags, f"paths.artifacts_dir={root}"]
        assert prepare_object.main(common + ["prepare.collision=hull", "prepare.n_metric_points=200"]) == 0
        assert sample_surface.main(common + ["sample.M=500"]) == 0
    return root


@pytest.mark.slow
def test_the_command_takes_distractors_from_their_own_folder(prim_artifacts):
    from tactile6d.cli.identify import library_of
    from tactile6d.cli.objects import KnownObjects

    known = KnownObjects(prim_artifacts, compose_config())
    assert library_of(None, known) == (["prim_box", "prim_cylinder"], ["shape_3"], [])
    assert library_of(["shape_3", "prim_box"], known) == (["prim_box"], ["shape_3"], [])
    # a configured distractor without artifacts is one too (its load error then names its stage)
    assert library_of(["prim_box", "shape_17"], known) == (["prim_box"], ["shape_17"], [])
    with pytest.raises(InputError, match="unknown object 'shape_x'"):
        library_of(["prim_box", "shape_x"], known)


def touching_sensors(artifacts, name, wanted):
    """Sensors at T_TRUE touching ``name``'s database points nearest the (point, normal) pairs ``wanted``."""
    from tactile6d.data import layout
    from tactile6d.data.hdf5 import read_artifact

    surface = read_artifact(layout.surface_file(artifacts, name), "surface")
    points, normals = surface["points"], surface["normals"]
    picks = [int(np.argmin(np.linalg.norm(points - t, axis=1) + 10 * np.linalg.norm(normals - n, axis=1)))
             for t, n in wanted]
    return T_TRUE @ sensor_poses_touching(points[picks], normals[picks], [0.1, 1.0, -2.0], 0.002)


@pytest.mark.slow
def test_a_distractor_is_estimated_by_name(prim_artifacts, tmp_path, capsys):
    """`tactile6d estimate --object shape_3` reads the distractor's artifacts from their own folder."""
    import json

    from tactile6d.data import layout
    from tactile6d.data.hdf5 import write_tactile_image

    surface = layout.distractors_dir(prim_artifacts)
    wanted = [((0.05, 0.0, 0.0), (1, 0, 0)), ((-0.05, 0.0, 0.0), (-1, 0, 0)), ((0.0, 0.0, 0.05), (0, 0, 1))]
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "poses_sensors.txt").write_text(g.poses_to_text(touching_sensors(surface, "shape_3", wanted)))
    for i in range(3):
        write_tactile_image(scene / f"Image_heatmap_{i}.png", np.full((320, 240, 3), 128, np.uint8))
    code = cli_main(["estimate", "--object", "shape_3", "--scene", str(scene), "--artifacts", str(prim_artifacts),
                     "--json", "select.method=baseline", "select.N=400"])
    out, err = capsys.readouterr()
    assert code == 0, err
    result = json.loads(out)
    assert result["object"] == "shape_3"
    assert np.linalg.norm(np.array(result["poses"][0])[:3, 3] - T_TRUE[:3, 3]) < 0.01


# Three faces of prim_box, as (point, outward normal) near which the sensors touch.
BOX_TOUCHES = [((0.05, 0.01, 0.0), (1, 0, 0)), ((0.0, -0.03, 0.01), (0, -1, 0)), ((0.02, 0.0, 0.02), (0, 0, 1))]


@pytest.mark.slow  # spawns two processes and a Dask cluster's two, each loading the library
def test_spread_screens_give_the_same_identification(prim_artifacts, dask_cluster):
    """identify.workers=2 screens the objects in two spawned processes, executor.address on a real Dask
    cluster's workers: the same candidates, probabilities and poses as one process."""
    T_sensors = touching_sensors(prim_artifacts, "prim_box", BOX_TOUCHES)
    results = {}
    runs = {"one process": ["identify.workers=1"], "2 local processes": ["identify.workers=2"],
            "dask": [f"executor.address={dask_cluster}"]}
    for label, overrides in runs.items():
        cfg = compose_config(["select.method=baseline", "identify.weights=[1,1,1]", *overrides])
        with Identifier.from_artifacts(["prim_box", "prim_cylinder"], prim_artifacts, cfg,
                                       distractors=["shape_3"]) as identifier:
            where = identifier.describe()
            results[label] = [identifier.identify(T_sensors) for _ in range(2)]  # the second: library loaded
        assert where == {"one process": "this process", "2 local processes": "2 local worker processes"}.get(
            label, f"Dask cluster at {dask_cluster}: 2 workers, 2 threads")
    one = results["one process"][0]
    assert one.best.name == "prim_box" and len(one.objects) == 3
    for label, found in results.items():
        for result in found:
            assert [o.name for o in result.objects] == [o.name for o in one.objects], label
            for a, b in zip(one.objects, result.objects):
                np.testing.assert_array_equal(a.candidate.features, b.candidate.features)
                assert a.probability == b.probability
                np.testing.assert_array_equal(a.pose, b.pose)


@pytest.mark.slow
def test_a_worker_reloads_the_library_for_a_new_identifier(prim_artifacts, monkeypatch):
    """A long-lived worker (a cluster's) keeps one library per identifier: the same source is loaded
    once, a new identifier's (new token, the artifacts may have changed) replaces it."""
    from tactile6d.estimation.identifier import LibrarySource, screen_task
    from tactile6d.runtime import executor

    cfg = compose_config(["select.method=baseline", "identify.weights=[1,1,1]", "identify.workers=1"])
    loads = []
    original = LibrarySource.load
    monkeypatch.setattr(LibrarySource, "load", lambda self: loads.append(self.token) or original(self))
    executor.clear_process_cache()
    T_sensors = touching_sensors(prim_artifacts, "prim_box", BOX_TOUCHES)
    with Identifier.from_artifacts(["prim_box"], prim_artifacts, cfg) as here:
        encoding = here.encode(T_sensors)
        expected = here.candidate("prim_box", T_sensors, encoding)
    relative = os.path.relpath(prim_artifacts)
    first, second = (LibrarySource.of(["prim_box"], [], relative, cfg) for _ in range(2))
    assert first.artifacts_dir == str(prim_artifacts.resolve()) and first.token != second.token
    assert first.cfg["identify"]["workers"] == 1 and first.cfg["executor"]["address"] is None
    try:
        for source in (first, first, second):
            got = screen_task(source, "prim_box", T_sensors, encoding)
            np.testing.assert_array_equal(got.features, expected.features)
    finally:
        executor.clear_process_cache()
    assert loads == [first.token, second.token]


def test_a_bad_worker_count_is_a_config_error(prim_artifacts):
    cfg = compose_config(["select.method=baseline", "identify.weights=[1,1,1]", "identify.workers=0"])
    with pytest.raises(ConfigError, match="identify.workers must be >= 1, got 0"):
        Identifier.from_artifacts(["prim_box"], prim_artifacts, cfg)


def test_bench_identify_without_artifacts_names_what_is_missing(tmp_path, capsys):
    assert cli_main(["bench", "identify", "--artifacts", str(tmp_path), "--object", "004_sugar_box"]) == 2
    err = capsys.readouterr().err
    assert "004_sugar_box" in err and "dvc repro" in err


def test_confusion_matrix_counts_by_hand():
    m = identity_model.confusion_matrix(np.array([0, 0, 1, 2, 2, 2]), np.array([0, 1, 1, 2, 2, 0]), 3)
    assert m.tolist() == [[1, 1, 0], [0, 1, 0], [1, 0, 2]]
    with pytest.raises(InputError):
        identity_model.confusion_matrix(np.array([0, 3]), np.array([0, 0]), 3)


def test_the_confusion_figure_draws_one_cell_per_pair():
    from tactile6d.evaluation import plots

    fig = plots.confusion_figure(np.array([[3, 1], [0, 4]]), ["box", "can"], "test")
    assert fig.axes[0].images[0].get_array().shape == (2, 2)
    assert sorted(t.get_text() for t in fig.axes[0].texts) == ["1", "3", "4"]


def test_the_confusion_figure_leaves_out_distractors_nothing_was_taken_for():
    from tactile6d.evaluation import plots

    # library: box, can (shown in the scenes), cone (taken for the can once), ball (never involved)
    matrix = np.array([[3, 0, 0, 0], [0, 3, 1, 0], [0, 0, 0, 0], [0, 0, 0, 0]])
    ax = plots.confusion_figure(matrix, ["box", "can", "cone", "ball"], "test").axes[0]
    assert ax.images[0].get_array().shape == (2, 3)
    assert [t.get_text() for t in ax.get_xticklabels()] == ["box", "can", "cone"]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["box", "can"]


@pytest.mark.slow  # identifies two scenes against two objects through the stage
def write_tiny_scenes(artifacts, name):
    """A scene set of two scenes: the box and the cylinder touched by three sensors each (blank images)."""
    from tactile6d.data import layout
    from tactile6d.data.hdf5 import write_artifact
    from tactile6d.sim.scenes import SceneSet

    box = touching_sensors(artifacts, "prim_box", BOX_TOUCHES)
    cylinder = touching_sensors(artifacts, "prim_cylinder", [((0.03, 0.0, 0.0), (1, 0, 0)),
                                                              ((-0.02, 0.02, 0.02), (-0.7, 0.7, 0)),
                                                              ((0.0, 0.0, 0.05), (0, 0, 1))])
    scenes = SceneSet(
        names=np.array(["box", "cylinder"]), objects=np.array(["prim_box", "prim_cylinder"]),
        T_world_object=np.stack([T_TRUE, T_TRUE]), T_world_sensors=np.stack([box, cylinder]),
        images=np.zeros((2, 3, 320, 240, 3), np.uint8), contact_points=np.zeros((2, 3, 3)),
        contact_normals=np.zeros((2, 3, 3)), contact_types=np.zeros((2, 3), dtype=np.int64),
    )
    write_artifact(layout.scenes_file(artifacts, name), "scenes", scenes.as_datasets())


@pytest.mark.slow
def test_the_identify_stage_writes_accuracy_and_the_confusion_matrix(prim_artifacts):
    import json

    from stages import identify as identify_stage
    from tactile6d.data import layout

    write_tiny_scenes(prim_artifacts, "tiny")
    assert identify_stage.main(["--scene-set", "tiny", f"paths.artifacts_dir={prim_artifacts}",
                                "objects.names=[prim_box,prim_cylinder]", "identify.distractors=[shape_3]",
                                "select.method=baseline", "identify.weights=[1,1,1]", "identify.workers=1"]) == 0
    metrics = json.loads(layout.metrics_file(prim_artifacts, "identify_tiny").read_text())
    assert metrics["n_scenes"] == 2 and metrics["objects"] == ["prim_box", "prim_cylinder", "shape_3"]
    assert metrics["confusion"] == [[1, 0, 0], [0, 1, 0], [0, 0, 0]]
    assert metrics["top1"] == 1.0 and metrics["top1_by_object"] == {"prim_box": 1.0, "prim_cylinder": 1.0}
    assert metrics["pose_of_correct"]["pos_err_cm_top1"] < 1.0


@pytest.mark.slow
def test_the_calibration_stage_fits_weights_on_the_calibration_scenes(prim_artifacts, tmp_path):
    """calibrate_identify screens the calibration scenes against the library (objects and distractors)
    and writes weights with which the true objects rank first."""
    import json
    import shutil

    from stages import calibrate_identify
    from tactile6d.data import layout

    artifacts = tmp_path / "artifacts"  # a copy: the module's fixture has no calibration set to keep clean
    shutil.copytree(prim_artifacts, artifacts)
    write_tiny_scenes(artifacts, "calibration")
    assert calibrate_identify.main([f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box,prim_cylinder]",
                                    "identify.distractors=[shape_3]", "select.method=baseline",
                                    "identify.workers=1"]) == 0
    out = json.loads(layout.identify_calibration_file(artifacts).read_text())
    assert out["objects"] == ["prim_box", "prim_cylinder", "shape_3"] and out["n_scenes"] == 2
    assert out["scene_set"] == "calibration"
    assert out["features"] == list(identity_model.FEATURES) and len(out["weights"]) == len(identity_model.FEATURES)
    assert np.all(np.isfinite(out["weights"]))
    assert out["top1_on_calibration_scenes"] == 1.0
    # the identifier loads these weights when identify.weights is null
    np.testing.assert_array_equal(load_weights(artifacts), out["weights"])


# ---- the sensors' own no-contact images ----------------------------------------------------------

UNIT_COLOURS = [(90, 100, 95), (97, 105, 100), (104, 110, 106)]  # three units' flat no-contact colours


@pytest.fixture(scope="module")
def units_library(prim_artifacts, tmp_path_factory):
    """A copy of the primitives' artifacts with the tiny autoencoder (method 'ours'), and a scene of
    prim_box whose three units each see no contact in their own colour, with background_<i>.png."""
    import shutil

    from test_estimator import write_tiny_autoencoder

    from tactile6d.data.hdf5 import write_tactile_image

    root = tmp_path_factory.mktemp("units")
    artifacts = root / "artifacts"
    shutil.copytree(prim_artifacts, artifacts)
    for name in ("prim_box", "prim_cylinder"):
        write_tiny_autoencoder(artifacts, 500, name)
    scene = root / "scene"
    scene.mkdir()
    (scene / "poses_sensors.txt").write_text(g.poses_to_text(touching_sensors(artifacts, "prim_box", BOX_TOUCHES)))
    for i, colour in enumerate(UNIT_COLOURS):
        write_tactile_image(scene / f"Image_heatmap_{i}.png", np.full((320, 240, 3), colour, np.uint8))
        write_tactile_image(root / f"unit_{i}.png", np.full((320, 240, 3), colour, np.uint8))
    shutil.copytree(scene, root / "scene_with_backgrounds")
    for i in range(3):
        shutil.copy(root / f"unit_{i}.png", root / "scene_with_backgrounds" / f"background_{i}.png")
    return root


def identify_json(capsys, root, scene, *options):
    code = cli_main(["identify", "--scene", str(root / scene), "--objects", "prim_box", "prim_cylinder",
                     "--artifacts", str(root / "artifacts"), "--json", *options, "identify.weights=[1,1,1]",
                     "select.N=200", "identify.screen.N=200", "identify.workers=1"])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_identify_reads_each_sensor_against_its_own_background(capsys, units_library):
    import json

    root = units_library
    files = [str(root / f"unit_{i}.png") for i in range(3)]
    # The units' flat images show no contact: said once, however many objects are estimated.
    no_contact = "no contact in any sensor's image: the pose rests on the sensor poses alone"
    code, by_files, err = identify_json(capsys, root, "scene", "--background", *files)
    assert code == 0 and err.count("\n") == 1 and err.startswith(f"warning: {root / 'scene'}: {no_contact}"), err
    code, in_folder, err = identify_json(capsys, root, "scene_with_backgrounds")
    assert code == 0, err
    note, warning = err.splitlines()
    assert note == (f"note: {root / 'scene_with_backgrounds'}: each sensor's image is read against its own "
                    "no-contact image background_<i>.png (i = 0..2)")
    assert warning.startswith(f"warning: {root / 'scene_with_backgrounds'}: {no_contact}")
    strip = lambda out: [{k: o[k] for k in ("name", "pose", "probability")} for o in json.loads(out)["objects"]]
    assert strip(by_files) == strip(in_folder)
    code, out, err = identify_json(capsys, root, "scene", "--background", *files[:2])
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err.startswith("error: 2 background images for 3 sensors")


@pytest.mark.slow
def test_identify_applies_the_sensor_offsets(capsys, units_library, tmp_path):
    """``--sensor-offsets`` reads the scene as if the corrected poses had been written into it."""
    import json
    import shutil

    from tactile6d.estimation.sensor_offsets import SensorOffsets, apply_sensor_offsets

    root = units_library
    rng = np.random.default_rng(0)
    E = g.make_pose(g.rotvec_to_rotmat(rng.normal(0, 0.02, (3, 3))), rng.normal(0, 0.001, (3, 3)))
    offsets = SensorOffsets(E, np.full((3, 3), 1e-4), np.full((3, 3), 1e-3), np.full(3, 5), np.zeros(3), np.ones(3))
    offsets.write(tmp_path / "offsets.json")
    corrected = root / "scene_corrected"
    shutil.copytree(root / "scene", corrected, dirs_exist_ok=True)
    reported = g.text_to_poses((root / "scene" / "poses_sensors.txt").read_text())
    (corrected / "poses_sensors.txt").write_text(g.poses_to_text(apply_sensor_offsets(reported, offsets)))
    files = [str(root / f"unit_{i}.png") for i in range(3)]
    code, applied, err = identify_json(capsys, root, "scene", "--background", *files,
                                       "--sensor-offsets", str(tmp_path / "offsets.json"))
    assert code == 0, err
    code, written, err = identify_json(capsys, root, "scene_corrected", "--background", *files)
    assert code == 0, err
    applied, written = json.loads(applied)["objects"], json.loads(written)["objects"]
    assert [o["name"] for o in applied] == [o["name"] for o in written]
    np.testing.assert_allclose([o["pose"] for o in applied], [o["pose"] for o in written], atol=1e-9)


@pytest.mark.slow
def test_several_scenes_in_one_call_each_give_a_line_or_an_error(capsys, units_library):
    """The library loaded once for three scenes: two identified as alone, the missing one an error line (and a JSON
    line with its error), exit status 1."""
    import json

    root = units_library
    alone = {scene: json.loads(identify_json(capsys, root, scene)[1]) for scene in ("scene", "scene_with_backgrounds")}
    code = cli_main(["identify", "--scene", str(root / "scene"), str(root / "missing"), str(root / "scene_with_backgrounds"),
                     "--objects", "prim_box", "prim_cylinder", "--artifacts", str(root / "artifacts"), "--json",
                     "identify.weights=[1,1,1]", "select.N=200", "identify.screen.N=200", "identify.workers=1"])
    out, err = capsys.readouterr()
    assert code == 1
    lines = [json.loads(line) for line in out.splitlines()]
    assert [line["scene"] for line in lines] == [str(root / s) for s in ("scene", "missing", "scene_with_backgrounds")]
    assert set(lines[1]) == {"scene", "error"} and "missing" in lines[1]["error"]
    strip = lambda result: [{k: o[k] for k in ("name", "pose", "probability")} for o in result["objects"]]
    assert strip(lines[0]) == strip(alone["scene"]) and strip(lines[2]) == strip(alone["scene_with_backgrounds"])
    assert err.splitlines()[-1] == "error: 1 of 3 scenes failed"


@pytest.mark.slow
def test_only_the_object_ranked_first_may_warn_that_it_presses_into_a_sensor(capsys, units_library, monkeypatch):
    """Wrong objects' best poses may press deep into a sensor; the warning is about the answer, so it comes once,
    for the object ranked first (forced here by a threshold below zero: every estimate would warn)."""
    from tactile6d.perception import inputs

    monkeypatch.setattr(inputs, "PENETRATION_WARNING", -1.0)
    code, out, err = identify_json(capsys, units_library, "scene", "--background",
                                   *[str(units_library / f"unit_{i}.png") for i in range(3)])
    assert code == 0, err
    import json

    first = json.loads(out)["objects"][0]["name"]
    pressed = [line for line in err.splitlines() if "the best pose presses" in line]
    assert len(pressed) == 1 and first in ("prim_box", "prim_cylinder"), err


@pytest.mark.slow
def test_plot_draws_the_most_probable_objects_estimate(prim_artifacts, tmp_path, capsys):
    """`tactile6d identify --plot` writes the winner's figure for one scene, one per scene into a folder for
    several, as `estimate --plot` does."""
    from tactile6d.data.hdf5 import write_tactile_image

    folders = []
    for parent in ("a", "b"):
        scene = tmp_path / parent / "triplet_0"
        scene.mkdir(parents=True)
        T_sensors = touching_sensors(prim_artifacts, "prim_box", BOX_TOUCHES)
        (scene / "poses_sensors.txt").write_text(g.poses_to_text(T_sensors))
        for i in range(3):
            write_tactile_image(scene / f"Image_heatmap_{i}.png", np.full((320, 240, 3), 128, np.uint8))
        folders.append(scene)
    common = ["identify", "--objects", "prim_box", "prim_cylinder", "--artifacts", str(prim_artifacts),
              "select.method=baseline", "select.N=400", "identify.weights=[1,1,1]", "identify.workers=1"]
    figure = tmp_path / "figure.png"
    code = cli_main([*common, "--scene", str(folders[0]), "--plot", str(figure)])
    _, err = capsys.readouterr()
    assert code == 0, err
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code = cli_main([*common, "--plot", str(tmp_path / "figures"), "--scene", *map(str, folders)])
    _, err = capsys.readouterr()
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "figures").iterdir()) == ["a_triplet_0.png", "b_triplet_0.png"]
