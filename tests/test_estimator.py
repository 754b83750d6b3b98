"""The online estimator on synthetic objects: recovery, diagnostics, input checks, artifact loading."""

import contextlib
import functools
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from omegaconf import OmegaConf

from tactile6d.core import geometry as g
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, ConfigError, InputError
from tactile6d.core.sensor import BOX_HALF_EXTENTS, bodies_overlap, sensor_poses_touching
from tactile6d.core.settings import Settings
from tactile6d.data import layout
from tactile6d.data.hdf5 import ImageSizeWarning, read_scene_dir, write_artifact
from tactile6d.estimation import estimator as est
from tactile6d.perception import contact_patch, photometric
from tactile6d.perception.encode import KNOWN_UNITS, load_background
from tactile6d.perception.inputs import PenetrationWarning, UnderdeterminedPoseWarning
from tactile6d.sim.meshes import pack_pieces
from tactile6d.sim.surface_sampling import sample_surface_even

HALF = np.array([0.05, 0.03, 0.08])  # a 10 x 6 x 16 cm box ...
CUTS = np.array([0.03, 0.015, 0.05])  # ... with its (+, +, +) corner cut off unevenly: no symmetry left
T_TRUE = g.make_pose(g.rotvec_to_rotmat(np.array([0.3, -1.1, 0.7])), [0.1, 0.0, 0.2])


def cut_box() -> trimesh.Trimesh:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) * HALF
    corners = corners[~np.all(corners > 0, axis=1)]
    cut = [HALF - np.eye(3)[a] * CUTS[a] for a in range(3)]
    return trimesh.convex.convex_hull(np.concatenate([corners, cut]))


@pytest.fixture(scope="module")
def world():
    """The cut box's database (800 points, random latent angles) and three sensors touching three
    database points on the -x, -y and -z faces (normals spanning 3-D: the pose is determined)."""
    mesh = cut_box()
    rng = np.random.default_rng(0)
    points, normals, _ = sample_surface_even(mesh, 800, rng)
    db_angles = rng.uniform(0.0, 0.6, len(points))
    targets = np.array([[-HALF[0], 0.01, -0.02], [0.0, -HALF[1], 0.03], [-0.02, 0.0, -HALF[2]]])
    idx = np.array([np.argmin(np.linalg.norm(points - t, axis=1)) for t in targets])
    # depth 2 mm puts the sensor's contact point exactly on the surface point: exact correspondences
    T_object_sensors = sensor_poses_touching(points[idx], normals[idx], rng.uniform(-np.pi, np.pi, 3), 0.002)
    return {
        "mesh": mesh,
        "points": points,
        "normals": normals,
        "db_angles": db_angles,
        "idx": idx,
        "T_world_sensors": T_TRUE @ T_object_sensors,
        "images": np.zeros((3, 320, 240, 3), dtype=np.uint8),
    }


# The synthetic worlds here have no tactile images to read contacts from: their sensors touch at the landmark.
LANDMARK_CONTACTS = {"select.contacts": "landmark", "rank.agreement_weight": 0.0}
# Sensor poses declared exact (the synthetic worlds' are): no penetration allowance and no sensor corrections,
# so that a score is the paper's, loss + deepest penetration.
EXACT_POSES = {"sensors.pose_sigma_mm": 0, "sensors.pose_sigma_deg": 0}


def settings(**overrides):
    """conf/'s select/optimize/rank/sensors sections with landmark contacts and ``section.key=value`` overrides."""
    overrides = {**LANDMARK_CONTACTS, **overrides}
    return Settings.from_cfg(compose_config([f"{k}={v}" for k, v in overrides.items()]))


@functools.cache
def small_patch_model() -> contact_patch.PatchModel:
    """A small contact-patch calibration (20 presses; the pipeline's has 60), made once per test process."""
    return contact_patch.calibrate(20, seed=0)


def make_estimator(world, angles=None, **overrides):
    """An estimator over the synthetic world; delta_h is pinned to 0.04 rad (the figures below assume it)."""
    overrides = {"select.delta_h": 0.04, **overrides}
    true_angles = world["db_angles"][world["idx"]] if angles is None else angles
    return est.Estimator(
        world["points"],
        [world["mesh"].vertices],
        world["db_angles"],
        encoder=lambda images: true_angles[: len(images)],
        settings=settings(**overrides),
        normals=world["normals"],
        surface=world["mesh"],
    )


def pose_errors(T, T_ref):
    return np.linalg.norm(T[:3, 3] - T_ref[:3, 3]), np.degrees(g.rotation_angle(T[:3, :3], T_ref[:3, :3]))


@pytest.mark.slow
def test_ours_recovers_the_true_pose_as_the_best(world):
    result = make_estimator(world, **EXACT_POSES).estimate(world["T_world_sensors"], world["images"])
    dt, dr = pose_errors(result.best, T_TRUE)
    assert dt < 0.002 and dr < 1.0
    assert result.poses.shape[1:] == (4, 4) and 1 <= len(result.poses) <= 5
    assert np.all(np.diff(result.scores) >= 0)
    assert result.penetrations.shape == (len(result.poses), 3)
    np.testing.assert_allclose(result.scores, result.losses + result.penetrations.max(axis=1))
    sel = result.selection
    # Omega_i: the points within 0.04 rad of the sensor's angle, ~ 0.08 / 0.6 of 800
    assert np.all((sel.omega_sizes > 40) & (sel.omega_sizes < 200))
    np.testing.assert_allclose(sel.delta_h, 0.04)
    assert not sel.widened.any()
    assert 1 <= sel.tuples.shape[0] <= 5000 and sel.delta_d > 0
    assert any((sel.tuples == world["idx"]).all(axis=1)), "the true tuple was not selected"
    assert set(result.seconds) == {"encode", "select", "optimize", "rank", "total"}
    assert result.seconds["total"] >= sum(result.seconds[s] for s in est.STEPS)


@pytest.mark.slow
def test_steps_called_one_by_one_give_the_same_estimate(world):
    e = make_estimator(world)
    T = world["T_world_sensors"]
    angles = e.encode(world["images"])
    contacts = e.contacts(T, world["images"])
    chosen = e.select(contacts, angles)
    hypotheses = e.optimize(contacts, chosen.tuples)
    ranked = e.rank(T, hypotheses.poses, hypotheses.losses, contacts)
    whole = e.estimate(T, world["images"])
    np.testing.assert_array_equal(ranked.poses, whole.poses)
    np.testing.assert_array_equal(ranked.scores, whole.scores)


@pytest.mark.slow
def test_an_image_far_from_every_database_angle_widens_its_delta_h(world):
    angles = world["db_angles"][world["idx"]].copy()
    angles[1] = 0.7  # the database angles lie in [0, 0.6]
    sel = make_estimator(world, angles=angles).estimate(world["T_world_sensors"], world["images"]).selection
    assert sel.widened.tolist() == [False, True, False]
    assert sel.delta_h[1] > 0.1 - 1e-9 and sel.omega_sizes[1] >= 1


@pytest.mark.slow
def test_baseline_uses_every_point_and_needs_no_images(world):
    e = est.Estimator(world["points"], [world["mesh"].vertices], settings=settings(**{"select.method": "baseline"}),
                      normals=world["normals"], surface=world["mesh"])
    result = e.estimate(world["T_world_sensors"])
    assert result.angles is None
    assert result.selection.omega_sizes.tolist() == [800, 800, 800]
    assert np.isnan(result.selection.delta_h).all()
    assert len(result.poses) >= 1 and result.n_hypotheses == result.selection.tuples.shape[0]


@pytest.mark.parametrize("n_sensors", [1, 2, 4, 5])
@pytest.mark.slow
def test_any_number_of_sensors_works(world, n_sensors):
    T = world["T_world_sensors"]
    if n_sensors > 3:
        # a fourth sensor on the +x face, a fifth on the +y face (selected by the beam: select.join_sensors is 3)
        targets, normals = [[HALF[0], -0.01, -0.03], [-0.02, HALF[1], -0.04]], np.eye(3)[:2]
        j = [int(np.argmin(np.linalg.norm(world["points"] - t, axis=1))) for t in targets[: n_sensors - 3]]
        T_extra = [T_TRUE @ sensor_poses_touching(world["points"][k], n, 0.3, 0.002) for k, n in zip(j, normals)]
        T = np.concatenate([T, np.stack(T_extra)])
        angles = np.append(world["db_angles"][world["idx"]], world["db_angles"][j])
    else:
        T = T[:n_sensors]
        angles = world["db_angles"][world["idx"]][:n_sensors]
    e = make_estimator(world, angles=angles, **{"select.N": 300})
    with pytest.warns(UnderdeterminedPoseWarning) if n_sensors == 1 else contextlib.nullcontext():
        result = e.estimate(T, np.zeros((n_sensors, 320, 240, 3), dtype=np.uint8))
    assert result.penetrations.shape[1] == n_sensors
    assert result.selection.tuples.shape == (result.selection.tuples.shape[0], n_sensors)
    if n_sensors > 3:
        assert pose_errors(result.best, T_TRUE)[0] < 0.002


@pytest.mark.slow
def test_faithful_gd_solver_runs_through_the_estimator(world):
    e = make_estimator(world, **{"select.N": 20, "optimize.solver": "gd", "optimize.n_steps": 30,
                                 "optimize.n_translations": 2, "optimize.normal_weight": 0.0})
    result = e.estimate(world["T_world_sensors"], world["images"])
    assert result.n_hypotheses == 2 * result.selection.tuples.shape[0]
    assert np.all(np.isfinite(result.scores))


def _bad_pose(kind):
    T = np.tile(np.eye(4), (3, 1, 1))
    if kind == "nan":
        T[1, 0, 3] = np.nan
    elif kind == "inf":
        T[2, 1, 1] = np.inf
    elif kind == "scaled":
        T[0, :3, :3] *= 1.1
    elif kind == "reflection":
        T[1, 0, 0] = -1.0
    elif kind == "last_row":
        T[0, 3, 0] = 0.5
    return T


@pytest.mark.parametrize(
    "kind,message",
    [("nan", "sensor pose 1 has NaN or infinite"), ("inf", "sensor pose 2 has NaN or infinite"),
     ("scaled", "sensor pose 0: the upper-left 3x3 block is not a rotation"),
     ("reflection", "sensor pose 1: the upper-left 3x3 block is not a rotation"),
     ("last_row", "sensor pose 0: the last row")],
)
@pytest.mark.slow
def test_bad_sensor_poses_are_rejected(world, kind, message):
    with pytest.raises(InputError, match=message):
        make_estimator(world).estimate(_bad_pose(kind), world["images"])


@pytest.mark.parametrize(
    "images,message",
    [(np.zeros((2, 320, 240, 3), np.uint8), "2 tactile images for 3 sensor poses"),
     (np.zeros((3, 240, 320, 3), np.uint8), r"image 0 is 320 wide x 240 high, .*rotated by 90 degrees"),
     ([np.zeros((320, 240, 3), np.uint8)] * 2 + [np.zeros((320, 240), np.uint8)], r"image 2 is 240 wide x 320 high, .*it has one channel"),
     (np.zeros((3, 320, 240, 3), np.float32), "image 0 has dtype float32"),
     (None, "needs one tactile image per sensor")],
)
@pytest.mark.slow
def test_bad_images_are_rejected(world, images, message):
    with pytest.raises(InputError, match=message):
        make_estimator(world).estimate(world["T_world_sensors"], images)


def test_ours_without_an_encoder_is_rejected(world):
    with pytest.raises(InputError, match="needs the database angles and an image encoder"):
        est.Estimator(world["points"], [world["mesh"].vertices], settings=settings(), normals=world["normals"])


# --- loading from artifacts ---------------------------------------------------------------------------


def write_object_artifacts(artifacts: Path, name: str, mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray):
    """object.h5 (the mesh, one convex piece) and surface.h5, as prepare_object and sample_surface write them."""
    write_artifact(layout.object_file(artifacts, name), "object",
                   {"vertices": mesh.vertices, "faces": mesh.faces, "metric_points": points,
                    **pack_pieces([(np.asarray(mesh.vertices), np.asarray(mesh.faces))])})
    write_artifact(layout.surface_file(artifacts, name), "surface",
                   {"points": points, "normals": normals, "face_index": np.zeros(len(points), int)})


def apart_sensor_poses(surface, start: int, n: int = 3) -> np.ndarray:
    """(n, 4, 4) sensors touching surface points from index ``start`` on, every 7th, skipping any whose
    DIGIT body would overlap one already placed (the estimator refuses overlapping sensors)."""
    chosen = []
    for i in range(start, start + 7 * len(surface["points"]), 7):
        i %= len(surface["points"])
        T = sensor_poses_touching(surface["points"][[i]], surface["normals"][[i]], 0.0, 0.002)[0]
        if not any(bodies_overlap(T, other) for other in chosen):
            chosen.append(T)
        if len(chosen) == n:
            return np.stack(chosen)
    raise AssertionError("no room for the sensors")


def write_tiny_autoencoder(artifacts: Path, n_points: int, name: str):
    """An untrained small autoencoder checkpoint, a latents.h5 whose angles cover [0, pi] (so that any
    image angle has database neighbours) and a small patch calibration: enough to run the 'ours' path
    end to end."""
    import torch

    from tactile6d.perception import autoencoder as ae

    cfg = dict(OmegaConf.to_container(OmegaConf.load(Path(__file__).parent.parent / "conf" / "ae" / "cpu.yaml")))
    cfg.update(input_height=32, input_width=24, channels=[4, 8, 8, 16])
    torch.manual_seed(0)  # build_model draws its weights from torch's global generator
    model = ae.build_model(cfg)
    ae.save_checkpoint(layout.ae_checkpoint(artifacts), model, ae.Normalisation(32, 24, (10.0, 10.0, 10.0), None, 0.0), cfg, {})
    latents = np.random.default_rng(1).normal(size=(n_points, 128)).astype(np.float32)
    write_artifact(layout.latents_file(artifacts, name), "latents",
                   {"latents": latents, "latent_nc": np.ones(128, np.float32),
                    "angles": np.linspace(0.0, np.pi, n_points)})
    layout.patch_model_file(artifacts).parent.mkdir(parents=True, exist_ok=True)
    contact_patch.save_model(small_patch_model(), layout.patch_model_file(artifacts))


@pytest.mark.slow
def test_missing_artifacts_name_the_dvc_command(tmp_path, world):
    with pytest.raises(ArtifactError) as missing_surface:
        est.Estimator.from_artifacts("prim_x", tmp_path)
    assert "surfaces/prim_x.h5: missing" in str(missing_surface.value)
    assert "`dvc repro sample_surface@prim_x`" in str(missing_surface.value)
    write_object_artifacts(tmp_path, "prim_x", world["mesh"], world["points"], world["normals"])
    with pytest.raises(ArtifactError) as missing_latents:
        est.Estimator.from_artifacts("prim_x", tmp_path)
    assert "latents/prim_x.h5: missing" in str(missing_latents.value)
    assert "`dvc repro encode_database@prim_x`" in str(missing_latents.value)
    baseline = est.Estimator.from_artifacts("prim_x", tmp_path, compose_config(["select.method=baseline"]))
    assert baseline.encoder is None and baseline.points.shape == (800, 3)


@pytest.mark.slow
def test_ours_from_artifacts_encodes_images_with_the_checkpoint(tmp_path, world, data_dir):
    write_object_artifacts(tmp_path, "prim_x", world["mesh"], world["points"], world["normals"])
    write_tiny_autoencoder(tmp_path, 800, "prim_x")
    e = est.Estimator.from_artifacts("prim_x", tmp_path, compose_config(["select.N=200"]), data_dir=data_dir)
    background = load_background(compose_config(), data_dir)
    assert background.shape == (320, 240, 3) and background.dtype == np.uint8
    # The no-contact image is the model's all-zero input: its angle is the same for every sensor.
    images = np.stack([background] * 3)
    angles = e.encode(images)
    assert angles.shape == (3,) and np.ptp(angles) < 1e-6
    result = e.estimate(world["T_world_sensors"], images)
    assert len(result.poses) >= 1 and np.allclose(result.angles, angles)


def test_missing_checkpoint_names_train_ae(tmp_path, world, data_dir):
    write_object_artifacts(tmp_path, "prim_x", world["mesh"], world["points"], world["normals"])
    write_tiny_autoencoder(tmp_path, 800, "prim_x")
    layout.ae_checkpoint(tmp_path).unlink()
    with pytest.raises(ArtifactError, match="dvc repro train_ae"):
        est.Estimator.from_artifacts("prim_x", tmp_path, data_dir=data_dir)


# --- accuracy options: best_n, normal-consistent selection, normal term, refinement ------------


@pytest.fixture(scope="module")
def off_grid(world):
    """Three sensors touching the cut box at surface points that are not database points (as in
    reality, 1-3 mm from the nearest), contact points on the surface."""
    from tactile6d.sim.surface_sampling import sample_surface_even

    points, normals, _ = sample_surface_even(world["mesh"], 800, np.random.default_rng(0))
    # The -x face, the -y face and the cut face (whose normal no symmetry of the uncut box maps
    # elsewhere: with three big faces only, the half turn about x would fit as well).
    cut = np.array([HALF - np.eye(3)[a] * CUTS[a] for a in range(3)])
    cut_normal = np.cross(cut[1] - cut[0], cut[2] - cut[0])
    cut_normal = cut_normal / np.linalg.norm(cut_normal) * np.sign(cut_normal @ (cut.mean(axis=0)))
    targets = np.array([[-HALF[0], 0.012, -0.021], [0.002, -HALF[1], 0.028], cut.mean(axis=0)])
    face_normals = np.array([[-1.0, 0, 0], [0, -1.0, 0], cut_normal])
    T_object_sensors = sensor_poses_touching(targets, face_normals, np.array([0.3, -1.0, 2.0]), 0.002)
    idx = np.array([np.argmin(np.linalg.norm(points - t, axis=1)) for t in targets])
    return {"normals": normals, "idx": idx, "T_world_sensors": T_TRUE @ T_object_sensors}


def make_full_estimator(world, off_grid, **overrides):
    overrides = {"rank.refine_offset": 0.0, **overrides}  # the contact points lie on the surface here
    return est.Estimator(
        world["points"], [world["mesh"].vertices], world["db_angles"],
        encoder=lambda images: world["db_angles"][off_grid["idx"]][: len(images)],
        settings=settings(**overrides), normals=off_grid["normals"], surface=world["mesh"],
    )


@pytest.mark.slow
def test_refinement_brings_an_off_grid_estimate_to_the_surface(world, off_grid):
    T, images = off_grid["T_world_sensors"], world["images"]
    plain = make_full_estimator(world, off_grid, **EXACT_POSES, **{"rank.refine": "false"}).estimate(T, images)
    refined = make_full_estimator(world, off_grid, **EXACT_POSES, **{"rank.refine": "true"}).estimate(T, images)
    dt0, _dr0 = pose_errors(plain.best, T_TRUE)
    dt, dr = pose_errors(refined.best, T_TRUE)
    assert dt < 5e-4 and dr < 0.5 and dt < dt0
    assert 1 <= len(refined.poses) <= 5 and np.all(np.diff(refined.scores) >= 0)
    np.testing.assert_allclose(refined.scores, refined.losses + refined.penetrations.max(axis=1))


@pytest.mark.slow
def test_all_switches_on_recover_the_off_grid_pose(world, off_grid):
    e = make_full_estimator(world, off_grid, **{"select.delta_d_rule": "best_n", "select.normal_tol_deg": 20,
                                                "optimize.normal_weight": 0.01, "rank.refine": "true"})
    result = e.estimate(off_grid["T_world_sensors"], world["images"])
    dt, dr = pose_errors(result.best, T_TRUE)
    assert dt < 5e-4 and dr < 0.5
    assert result.selection.tuples.shape[0] <= 5000


@pytest.mark.slow
def test_two_sensors_only_the_normals_tell_the_rotation_about_their_line(world, off_grid):
    # Two contacts (database points on the -x and -y faces) fix the pose up to a turn about the line
    # through them: positions alone cannot tell those poses apart, the contact normals can.
    T, images = world["T_world_sensors"][:2], world["images"][:2]
    exact = dict(off_grid, idx=world["idx"])
    on = make_full_estimator(world, exact).estimate(T, images)  # the defaults: both normal switches on
    dt, dr = pose_errors(on.best, T_TRUE)
    assert dt < 1e-4 and dr < 0.1 and on.losses[0] < 1e-6
    off = make_full_estimator(world, exact, **{"select.normal_tol_deg": "null", "optimize.normal_weight": 0.0,
                                               "rank.refine": "false"}).estimate(T, images)
    assert pose_errors(off.best, T_TRUE)[1] > 5.0


@pytest.mark.slow
def test_switches_that_need_normals_or_a_surface_say_so(world):
    with pytest.raises(InputError, match="normals"):
        est.Estimator(world["points"], [world["mesh"].vertices], world["db_angles"], encoder=lambda x: x,
                      settings=settings(**{"select.normal_tol_deg": 20}))
    with pytest.raises(InputError, match="surface"):
        est.Estimator(world["points"], [world["mesh"].vertices], world["db_angles"], encoder=lambda x: x,
                      settings=settings(**{"rank.refine": "true"}), normals=world["normals"])


@pytest.mark.slow
def test_a_sensor_with_its_own_background(tmp_path, world):
    """A real sensor's no-contact image replaces the simulated one: the encoder subtracts it."""
    write_object_artifacts(tmp_path, "prim_x", world["mesh"], world["points"], world["normals"])
    write_tiny_autoencoder(tmp_path, 800, "prim_x")
    own = np.random.default_rng(5).integers(0, 255, (320, 240, 3), dtype=np.uint8)
    e = est.Estimator.from_artifacts("prim_x", tmp_path, compose_config(["select.N=200"]), background=own)
    np.testing.assert_array_equal(e.encoder.background, own)
    # its own no-contact image encodes like any other no-contact image: all sensors get one angle
    angles = e.encode(np.stack([own] * 3))
    assert np.ptp(angles) < 1e-6
    with pytest.raises(InputError, match="320"):
        est.Estimator.from_artifacts("prim_x", tmp_path, compose_config(), background=own[:100])


@pytest.mark.parametrize("bad", [{"select.delta_h": 0.6}, {"select.delta_h": 0.0}, {"select.delta_h_widen_step": 0.0}])
@pytest.mark.slow
def test_inconsistent_delta_h_settings_are_a_config_error_not_a_failed_estimate(bad):
    # delta_h above delta_h_max (0.5) used to fail every estimate one by one as "no match"
    with pytest.raises(ConfigError, match="delta_h"):
        settings(**bad)


@pytest.mark.slow
def test_normal_switches_apply_up_to_normal_max_sensors(world, off_grid):
    T, images = off_grid["T_world_sensors"], world["images"]
    on = {"select.normal_tol_deg": 45, "optimize.normal_weight": 0.01, "rank.refine": "false"}
    off = {"select.normal_tol_deg": "null", "optimize.normal_weight": 0.0, "rank.refine": "false"}
    limited = {**on, "select.normal_max_sensors": 2, "optimize.normal_max_sensors": 2}
    three = make_full_estimator(world, off_grid, **limited).estimate(T, images)
    np.testing.assert_array_equal(three.poses, make_full_estimator(world, off_grid, **off).estimate(T, images).poses)
    two = make_full_estimator(world, off_grid, **limited).estimate(T[:2], images[:2])
    np.testing.assert_array_equal(two.poses, make_full_estimator(world, off_grid, **on).estimate(T[:2], images[:2]).poses)
    positions_only = make_full_estimator(world, off_grid, **off).estimate(T[:2], images[:2])
    assert not np.array_equal(two.selection.tuples, positions_only.selection.tuples)  # the check did apply


@pytest.mark.parametrize("key", ["select.normal_max_sensors", "optimize.normal_max_sensors"])
def test_normal_max_sensors_must_be_a_positive_count(key):
    with pytest.raises(ConfigError, match="normal_max_sensors"):
        settings(**{key: 0})


@pytest.mark.slow
def test_join_sensors_is_null_or_at_least_two():
    with pytest.raises(ConfigError, match="select.join_sensors"):
        settings(**{"select.join_sensors": 1})
    assert settings(**{"select.join_sensors": "null"}).select.join_sensors is None


# --- a hand whose units differ: one no-contact image per sensor ---------------------------------------

UNIT_GAINS = np.array([[0.9, 0.95, 1.0], [1.0, 1.0, 1.0], [1.1, 1.05, 1.0]])  # per unit, per RGB channel
UNIT_OFFSETS = np.array([6.0, 0.0, -5.0])  # grey levels


def unit_background(background: np.ndarray, i: int) -> np.ndarray:
    """Unit i's no-contact image (320, 240, 3) uint8 RGB: the simulated one with the unit's channel gains
    and offset, as DIGITs whose LEDs and cameras differ a little."""
    return np.clip(np.rint(background * UNIT_GAINS[i] + UNIT_OFFSETS[i]), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def three_units(world, data_dir, tmp_path_factory):
    """The world's three sensors pressing the cut box, rendered twice: over the common simulated
    background, and each over its own unit's (``unit_background``), with the same noise; the cut box's
    artifacts with the tiny autoencoder."""
    from tactile6d.sim.render import DigitRenderer

    common = load_background(compose_config(), data_dir)
    units = np.stack([unit_background(common, i) for i in range(3)])
    T = world["T_world_sensors"]

    def render(background_rgb, i):
        renderer = DigitRenderer.from_default_config(np.ascontiguousarray(background_rgb[..., ::-1]))
        return renderer.render(world["mesh"], T_TRUE, T[i], seed=10 + i).image

    artifacts = tmp_path_factory.mktemp("units")
    write_object_artifacts(artifacts, "prim_x", world["mesh"], world["points"], world["normals"])
    write_tiny_autoencoder(artifacts, 800, "prim_x")
    return {"common": common, "units": units, "artifacts": artifacts,
            "over_common": np.stack([render(common, i) for i in range(3)]),
            "over_units": np.stack([render(units[i], i) for i in range(3)])}


@pytest.mark.slow
def test_each_unit_read_against_its_own_background_reads_like_the_common_rendering(world, three_units):
    def estimator(background, *overrides):
        return est.Estimator.from_artifacts("prim_x", three_units["artifacts"],
                                            compose_config(["select.N=200", *overrides]), background=background)

    e = estimator(three_units["common"])
    T = world["T_world_sensors"]
    reference = e.estimate(T, three_units["over_common"])
    assert reference.contacts.from_patch.all()  # every press is read from its patch
    own = e.estimate(T, three_units["over_units"], backgrounds=three_units["units"])
    # One background for all (the common one, which unit 1 has) misreads the units that differ from it, when
    # their images are read as given (select.align_light=false).
    as_given = estimator(three_units["common"], "select.align_light=false")
    wrong = as_given.estimate(T, three_units["over_units"])
    reference_as_given = as_given.estimate(T, three_units["over_common"])
    # The same imprints over other backgrounds, each read against its own, read like the reference: not to
    # the bit, as the dark pixels clip at 0 differently. Measured: contacts 0.15, 0, 0.03 mm and angles
    # 7e-4, 0, 1e-4 rad from the reference's; with the one background 6.6, 0, 2.5 mm and 2.3e-3, 0, 4.9e-3 rad.
    own_off = np.linalg.norm(own.contacts.points - reference.contacts.points, axis=1)
    wrong_off = np.linalg.norm(wrong.contacts.points - reference_as_given.contacts.points, axis=1)
    assert own_off.max() < 3e-4 and wrong_off[0] > 2e-3 and wrong_off[2] > 1e-3
    own_dh, wrong_dh = np.abs(own.angles - reference.angles), np.abs(wrong.angles - reference_as_given.angles)
    assert own_dh.max() < 1e-3 and np.all(wrong_dh[[0, 2]] > 3 * own_dh[[0, 2]])
    assert own_dh[1] == wrong_dh[1] == 0.0  # unit 1's background is the common one
    dt, dr = pose_errors(own.best, reference.best)
    assert dt < 1e-3 and dr < 2.0  # measured 0.23 mm, 0.7 deg; with the one background 4 mm, 175 deg
    assert pose_errors(wrong.best, reference_as_given.best)[0] > 2e-3
    # Aligning each image's light to the one background (the default) absorbs most of what tells these units
    # apart, their channel gains and offsets (a gain and a gamma per channel, not an offset: the cut box
    # presses 89 % of the gel, and the fit finds the light on the rest): their contacts read like the
    # reference's again, within a millimetre where read as given they are 6.6 and 2.5 mm off. Measured 0.31,
    # 0 and 0.61 mm.
    aligned = e.estimate(T, three_units["over_units"])
    assert aligned.light[0].applied and aligned.light[2].applied
    assert np.linalg.norm(aligned.contacts.points - reference.contacts.points, axis=1).max() < 1e-3
    # The estimator built with the units' backgrounds reads the same without a per-call argument.
    built = estimator(three_units["units"])
    np.testing.assert_array_equal(built.estimate(T, three_units["over_units"]).angles, own.angles)


@pytest.mark.slow
def test_the_default_background_path_is_unchanged_by_per_sensor_backgrounds(world, three_units):
    """Passing the common background once per sensor gives the bits of passing it once."""
    e = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], compose_config(["select.N=200"]),
                                     background=three_units["common"])
    T, images = world["T_world_sensors"], three_units["over_common"]
    once = e.estimate(T, images)
    each = e.estimate(T, images, backgrounds=np.stack([three_units["common"]] * 3))
    np.testing.assert_array_equal(each.angles, once.angles)
    np.testing.assert_array_equal(each.poses, once.poses)


@pytest.mark.slow
def test_a_no_contact_image_of_another_unit_is_warned_about(world, three_units):
    """Each unit's images read against another unit's no-contact image (the common one turned half a turn:
    the same LEDs laid out otherwise) give a UnitWarning per image; against their own, none."""
    e = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], compose_config(["select.N=200"]),
                                     background=three_units["common"])
    T, images = world["T_world_sensors"], three_units["over_units"]
    with pytest.warns(photometric.UnitWarning) as caught:
        result = e.estimate(T, images, backgrounds=np.ascontiguousarray(three_units["common"][::-1, ::-1]))
    unit_warnings = [str(w.message) for w in caught if w.category is photometric.UnitWarning]
    assert [m.split(":")[0] for m in unit_warnings] == ["image 0", "image 1", "image 2"]
    assert all(fit.from_another_unit for fit in result.light)
    # The contacts so misread press the best pose into a sensor; the warning then blames the images, not the poses.
    pressed = [str(w.message) for w in caught if w.category is PenetrationWarning]
    assert len(pressed) == 1 and "Images 0, 1, 2 were read against another unit's no-contact image" in pressed[0]
    assert "T_world_sensor" not in pressed[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error", photometric.UnitWarning)
        e.estimate(T, images, backgrounds=three_units["units"])


@pytest.fixture(scope="module")
def tacto_unit(world, data_dir):
    """The world's three presses rendered over TACTO's example DIGIT's no-contact image (a known unit,
    ``encode.KNOWN_UNITS``) -> images (3, 320, 240, 3) RGB."""
    import cv2

    from tactile6d.sim.render import DigitRenderer

    bgr = cv2.imread(str(data_dir / "digit" / "tacto" / "bg_digit_240_320.jpg"))
    if bgr is None:
        pytest.skip("TACTO's background image is not in the data directory")
    renderer = DigitRenderer.from_default_config(bgr)
    T = world["T_world_sensors"]
    return np.stack([renderer.render(world["mesh"], T_TRUE, T[i], seed=10 + i).image for i in range(3)])


@pytest.mark.slow
def test_images_of_a_known_unit_passed_without_its_no_contact_image_are_read_against_it(world, three_units,
                                                                                       tacto_unit, data_dir):
    """No no-contact image passed: each image of TACTO's unit disagrees with the default (the paper's unit's) and
    is read against TACTO's, which it agrees with, as if that had been passed, saying so. A no-contact image the
    user gives is never replaced: there the images are only warned about."""
    images, T = tacto_unit, world["T_world_sensors"]
    cfg = compose_config(["select.N=200"])
    default = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], cfg, data_dir=data_dir)
    with pytest.warns(photometric.KnownUnitWarning) as caught:
        known = default.estimate(T, images)
    messages = [str(w.message) for w in caught if w.category is photometric.KnownUnitWarning]
    assert [m.split(":")[0] for m in messages] == ["image 0", "image 1", "image 2"]
    assert all("agrees with TACTO's example DIGIT (digit/tacto/bg_digit_240_320.jpg)'s" in m for m in messages)
    assert not any(w.category is photometric.UnitWarning for w in caught)  # read right: nothing else to say
    assert not any(fit.from_another_unit for fit in known.light)
    tacto = default.known_units.images()["TACTO's example DIGIT (digit/tacto/bg_digit_240_320.jpg)"]
    given = default.estimate(T, images, backgrounds=tacto)
    np.testing.assert_array_equal(known.contacts.points, given.contacts.points)
    np.testing.assert_array_equal(known.angles, given.angles)
    np.testing.assert_array_equal(known.poses, given.poses)
    # Identification reads the scene once for every object, the same way.
    from tactile6d.estimation.identifier import Identifier

    identifier = Identifier({"prim_x": default})
    with pytest.warns(photometric.KnownUnitWarning):
        read = identifier.encode(T, images)
    read_given = identifier.encode(T, images, backgrounds=tacto)
    np.testing.assert_array_equal(read.contacts.points, read_given.contacts.points)
    np.testing.assert_array_equal(read.latents, read_given.latents)
    # The user's own no-contact image (here the paper's unit's, passed): warned about, not replaced.
    own = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], cfg, data_dir=data_dir,
                                       background=three_units["common"])
    assert own.known_units is None
    with pytest.warns(photometric.UnitWarning) as caught:
        result = own.estimate(T, images)
    assert not any(w.category is photometric.KnownUnitWarning for w in caught)
    assert all(fit.from_another_unit for fit in result.light)
    assert read.misread == ()  # what the identifier's PenetrationWarning names (estimate's, above)
    with pytest.warns(photometric.UnitWarning):
        assert Identifier({"prim_x": own}).encode(T, images).misread == (0, 1, 2)
    # Images of the default's own unit are read against it, the known units never looked at.
    with warnings.catch_warnings():
        warnings.simplefilter("error", photometric.UnitWarning)
        default.estimate(T, three_units["over_common"])
    # A tracker decides at its first frame and reads every frame against the same no-contact images, its
    # re-detections and its updates alike: as if TACTO's had been passed with every frame.
    from tactile6d.estimation.tracker import Tracker

    tracker, passed = Tracker(default), Tracker(default)
    assert tracker.estimator.known_units is None and tracker.estimator.points is default.points
    with pytest.warns(photometric.KnownUnitWarning) as caught:
        first = tracker.update(T, images)
    assert len([w for w in caught if w.category is photometric.KnownUnitWarning]) == 3
    assert not any(w.category is photometric.UnitWarning for w in caught)
    reference = passed.update(T, images, backgrounds=tacto)
    np.testing.assert_array_equal(first.pose, reference.pose)
    with warnings.catch_warnings():
        warnings.simplefilter("error", photometric.UnitWarning)  # decided once: nothing more to say
        for redetect in (False, True):
            np.testing.assert_array_equal(tracker.update(T, images, redetect=redetect).pose,
                                          passed.update(T, images, backgrounds=tacto, redetect=redetect).pose)


@pytest.mark.slow
def test_your_own_units_are_known_beside_the_data_directorys(world, three_units, data_dir):
    """A unit of the user's whose LEDs differ from every known unit's (the paper's unit's no-contact image turned
    half a turn), given as ``known_units``: its images passed without a no-contact image are read against it, as
    if it had been passed, and the warning names it; without it, no known unit agrees and a UnitWarning says so."""
    turned = np.ascontiguousarray(three_units["common"][::-1, ::-1])
    over_common = three_units["over_common"].astype(np.int16)
    images = np.clip(over_common - three_units["common"] + turned, 0, 255).astype(np.uint8)
    T, cfg = world["T_world_sensors"], compose_config(["select.N=200"])
    mine = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], cfg, data_dir=data_dir,
                                        known_units={"lab unit 7": turned})
    with pytest.warns(photometric.KnownUnitWarning) as caught:
        known = mine.estimate(T, images)
    messages = [str(w.message) for w in caught if w.category is photometric.KnownUnitWarning]
    assert len(messages) == 3 and all("agrees with lab unit 7's" in m for m in messages)
    assert not any(w.category is photometric.UnitWarning for w in caught)
    given = mine.estimate(T, images, backgrounds=turned)
    np.testing.assert_array_equal(known.contacts.points, given.contacts.points)
    with pytest.warns(photometric.KnownUnitWarning):  # the contacts alone, read as estimate reads them
        _, read = mine.read_scene(T, images)
    np.testing.assert_array_equal(read.points, given.contacts.points)
    np.testing.assert_array_equal(known.poses, given.poses)
    from tactile6d.estimation.identifier import Identifier  # identification reads the scene the same way

    with Identifier.from_artifacts(["prim_x"], three_units["artifacts"], compose_config(["identify.workers=1"]),
                                   data_dir, calibrated=False, known_units={"lab unit 7": turned}) as identifier:
        with pytest.warns(photometric.KnownUnitWarning, match="agrees with lab unit 7's"):
            read = identifier.encode(T, images)
    np.testing.assert_array_equal(read.contacts.points, given.contacts.points)
    plain = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], cfg, data_dir=data_dir)
    with pytest.warns(photometric.UnitWarning) as caught:
        plain.estimate(T, images)
    assert not any(w.category is photometric.KnownUnitWarning for w in caught)
    with pytest.raises(InputError, match="pass a background or known units, not both"):
        est.Estimator.from_artifacts("prim_x", three_units["artifacts"], cfg, data_dir=data_dir,
                                     background=three_units["common"], known_units={"lab unit 7": turned})
    with pytest.raises(InputError, match="is already a known unit's"):
        est.Estimator.from_artifacts("prim_x", three_units["artifacts"], cfg, data_dir=data_dir,
                                     known_units={next(iter(KNOWN_UNITS)): turned})
    with pytest.raises(InputError, match=r"unit 'lab unit 7': .*one \(320, 240, 3\) image per unit"):
        est.Estimator.from_artifacts("prim_x", three_units["artifacts"], cfg, data_dir=data_dir,
                                     known_units={"lab unit 7": np.stack([turned] * 3)})


@pytest.mark.slow
def test_one_no_contact_latent_serves_every_unit(three_units):
    """The model sees image - background: each unit's own no-contact image is the same (zero) input, so a
    per-sensor no-contact latent would be one latent repeated."""
    e = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], compose_config(["select.N=200"]),
                                     background=three_units["units"])
    latents = e.encoder.latents(three_units["units"])
    np.testing.assert_array_equal(latents, np.broadcast_to(latents[0], latents.shape))


COLOUR = np.broadcast_to(np.array([60, 90, 120], np.uint8), (320, 240, 3))  # a flat colour no-contact image


@pytest.mark.parametrize("backgrounds,message", [
    (np.stack([COLOUR] * 2), "2 background images for 3 sensors"),
    (np.zeros((240, 320, 3), np.uint8), r"background is 320 wide x 240 high, .*rotated by 90 degrees"),
    (np.stack([COLOUR] * 3).astype(np.float32), "background 0 has dtype float32"),
    (np.full((320, 240, 3), 90, np.uint8), "background is grey"),
    ([COLOUR, COLOUR, COLOUR[..., 0]], r"background 2 is 240 wide x 320 high, .*it has one channel"),
])
@pytest.mark.slow
def test_bad_backgrounds_are_named(world, three_units, backgrounds, message):
    e = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], compose_config(["select.N=200"]),
                                     background=three_units["common"])
    with pytest.raises(InputError, match=message):
        e.estimate(world["T_world_sensors"], three_units["over_common"], backgrounds=backgrounds)
    with pytest.raises(InputError, match=message):  # the same when the estimator is built with them
        est.Estimator.from_artifacts("prim_x", three_units["artifacts"], compose_config(["select.N=200"]),
                                     background=backgrounds).estimate(world["T_world_sensors"],
                                                                      three_units["over_common"])


@pytest.mark.slow
def test_images_read_wrong_are_refused_before_any_work(world, three_units, data_dir):
    e = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], compose_config(["select.N=200"]),
                                     background=three_units["common"])
    T, images = world["T_world_sensors"], three_units["over_common"]
    grey = images.copy()
    grey[0] = images[0].mean(axis=-1, keepdims=True).astype(np.uint8)
    with pytest.raises(InputError, match="image 0 is grey"):
        e.estimate(T, grey)
    # The paper's images (their presses leave most of the gel free: whole-gel presses give no evidence)
    paper = read_scene_dir(data_dir / "caddeo2023/triplets/004_sugar_box/triplet_1")[1]
    e.estimate(T, paper)
    with pytest.raises(InputError, match="image 1 looks like BGR"):
        e.estimate(T, np.stack([paper[0], paper[1, ..., ::-1], paper[2]]))
    # against a unit's own background: the same paper image on unit 2, swapped
    units = np.stack([three_units["common"], three_units["common"], three_units["units"][2]])
    on_unit = paper.copy()
    on_unit[2] = np.clip(np.rint(paper[2] * UNIT_GAINS[2] + UNIT_OFFSETS[2]), 0, 255).astype(np.uint8)
    e.estimate(T, on_unit, backgrounds=units)
    with pytest.raises(InputError, match="image 2 looks like BGR"):
        e.estimate(T, np.concatenate([on_unit[:2], on_unit[2:, ..., ::-1]]), backgrounds=units)


@pytest.mark.slow
def test_bodies_may_overlap_by_the_declared_sensor_pose_error(world):
    """Two bodies 3 mm into each other: within two standard deviations of two sensors' relative error at the
    default 1.5 mm and 1.5 deg (4.7 mm), so a hand's reported poses are read; declared exact, they cannot
    both be right."""
    T = world["T_world_sensors"].copy()
    T[2] = T[0]
    T[2, :3, 3] += (2 * BOX_HALF_EXTENTS[1] - 0.003) * T[0, :3, 1]
    make_estimator(world).check_scene(T, world["images"])
    with pytest.raises(InputError, match="sensors 0 and 2 overlap"):
        make_estimator(world, **EXACT_POSES).check_scene(T, world["images"])


@pytest.mark.slow
def test_overlapping_sensors_and_one_sensor(world):
    T = world["T_world_sensors"].copy()
    T[2] = T[0]
    T[2, :3, 3] += 0.005 * T[0, :3, 1]  # 5 mm beside sensor 0
    with pytest.raises(InputError, match="sensors 0 and 2 overlap"):
        make_estimator(world).estimate(T, world["images"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # three sensors: no warning
        make_estimator(world).estimate(world["T_world_sensors"], world["images"])


# --- images at another resolution of the DIGIT's field of view ---------------------------------------------


@pytest.mark.slow
def test_images_at_another_size_are_read_resized(world, three_units):
    """Each pixel repeated 2 x 2 (a 480 x 640 image of the same field of view) gives the estimate of the 240 x 320
    images to the bit: averaged back down, four equal pixels are that pixel. Rendered at 120 x 160 (each pixel the
    mean of 2 x 2, as TACTO's default size gives) and enlarged, the presses are read within a millimetre."""
    import cv2

    e = est.Estimator.from_artifacts("prim_x", three_units["artifacts"], compose_config(["select.N=200"]),
                                     background=three_units["common"])
    T, images = world["T_world_sensors"], three_units["over_common"]
    reference = e.estimate(T, images)
    vga = images.repeat(2, axis=1).repeat(2, axis=2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        enlarged = e.estimate(T, vga, backgrounds=three_units["common"].repeat(2, axis=0).repeat(2, axis=1))
    said = [str(w.message) for w in caught if w.category is ImageSizeWarning]
    assert sorted(said) == [f"{name} is 480 wide x 640 high: read resized to the DIGIT's 240 x 320 (averaged down)"
                            for name in ("background", "image 0", "image 1", "image 2")]
    np.testing.assert_array_equal(enlarged.poses, reference.poses)
    np.testing.assert_array_equal(enlarged.angles, reference.angles)

    def small(image):
        return cv2.resize(image, (120, 160), interpolation=cv2.INTER_AREA)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        coarse = e.estimate(T, [small(image) for image in images], backgrounds=small(three_units["common"]))
    assert sum(w.category is ImageSizeWarning and "enlarged, bilinear" in str(w.message) for w in caught) == 4
    assert coarse.contacts.from_patch.all()
    assert np.linalg.norm(coarse.contacts.points - reference.contacts.points, axis=1).max() < 1e-3
