"""``tactile6d calibrate-sensors`` on rendered grasps of an ellipsoid at known poses, through a hand whose sensors
are each off by a bias of their own; then ``estimate --sensor-offsets`` and ``track --sensor-offsets``, which must
read the corrected poses exactly as if they had been written into the scene folders."""

import contextlib
import io
import json

import numpy as np
import pytest
import trimesh

from tactile6d import cli
from tactile6d.core import geometry as g
from tactile6d.core.sensor import GEL_CENTER, bodies_overlap, sensor_poses_touching
from tactile6d.data import sequence_dirs
from tactile6d.data.hdf5 import read_scene_dir, read_tactile_image, write_tactile_image
from tactile6d.estimation.sensor_offsets import SensorOffsets, apply_sensor_offsets
from tactile6d.sim.render import DigitRenderer
from tactile6d.sim.surface_sampling import sample_surface_even

OBJECT = "prim_ellipsoid"
GRASPS = 6
# A flat colour no-contact image (a grey one is refused as no DIGIT's), RGB.
NO_CONTACT = np.broadcast_to(np.array([120, 128, 124], np.uint8), (320, 240, 3))
QUICK = ["select.N=200"]


def ellipsoid() -> trimesh.Trimesh:
    """Semi-axes 45, 35 and 28 mm: curved everywhere, so each press gives a well-defined contact."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    mesh.apply_scale([0.045, 0.035, 0.028])
    return mesh


def three_sensors(points, normals, rng) -> np.ndarray:
    """(3, 4, 4) sensors touching random surface points (contact point on the surface), bodies apart."""
    chosen = []
    while len(chosen) < 3:
        k = int(rng.integers(len(points)))
        T = sensor_poses_touching(points[[k]], normals[[k]], rng.uniform(-np.pi, np.pi), 0.0018)[0]
        if not any(bodies_overlap(T, other) for other in chosen):
            chosen.append(T)
    return np.stack(chosen)


@pytest.fixture(scope="module")
def hand(tmp_path_factory):
    """The ellipsoid's artifacts (tiny autoencoder, small patch calibration), a hand bias per sensor (1.5 mm and
    1.5 deg per axis, sensor frame), and GRASPS + 1 rendered grasp folders: poses_sensors.txt as the hand reports
    them (``true @ bias``), the images of the true poses, object_pose.txt; the last is not a calibration grasp."""
    from test_estimator import write_object_artifacts, write_tiny_autoencoder

    mesh = ellipsoid()
    rng = np.random.default_rng(0)
    points, normals, _ = sample_surface_even(mesh, 800, rng)
    artifacts = tmp_path_factory.mktemp("artifacts")
    write_object_artifacts(artifacts, OBJECT, mesh, points, normals)
    write_tiny_autoencoder(artifacts, 800, OBJECT)
    bias = g.make_pose(g.rotvec_to_rotmat(rng.normal(0, np.radians(1.5), (3, 3))), rng.normal(0, 0.0015, (3, 3)))
    renderer = DigitRenderer.from_default_config(np.ascontiguousarray(NO_CONTACT[..., ::-1]), workers=1)
    root = tmp_path_factory.mktemp("grasps")
    folders, true_poses = [], []
    for k in range(GRASPS + 1):
        T_world_object = g.make_pose(g.random_rotations(1, rng)[0], [0.1, 0.0, 0.2])
        true = T_world_object @ three_sensors(points, normals, rng)
        folder = root / f"grasp_{k}"
        folder.mkdir()
        (folder / "poses_sensors.txt").write_text(g.poses_to_text(true @ bias))
        (folder / "object_pose.txt").write_text(g.pose_to_line(T_world_object) + "\n")
        for i in range(3):
            write_tactile_image(folder / f"Image_heatmap_{i}.png", renderer.render(mesh, T_world_object, true[i], k + i).image)
        for i in range(3):
            write_tactile_image(folder / f"background_{i}.png", np.ascontiguousarray(NO_CONTACT))
        folders.append(folder)
        true_poses.append(true)
    return {"artifacts": artifacts, "bias": bias, "folders": folders, "true": np.stack(true_poses)}


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def calibrated(hand, tmp_path_factory):
    """The offsets fitted from the first GRASPS folders, and what the command printed."""
    out = tmp_path_factory.mktemp("offsets") / "offsets.json"
    # A module-scoped fixture has no capsys: the command's streams are redirected instead.
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = cli.main(["calibrate-sensors", "--object", OBJECT, "--scene", *map(str, hand["folders"][:GRASPS]),
                         "--artifacts", str(hand["artifacts"]), "--out", str(out), *QUICK])
    return {"code": code, "out": stdout.getvalue(), "err": stderr.getvalue(), "file": out}


def gel_shift_axes(error: np.ndarray) -> np.ndarray:
    return np.einsum("lab,b->la", error[:, :3, :3], GEL_CENTER) + error[:, :3, 3] - GEL_CENTER


@pytest.mark.slow
def test_the_offsets_take_out_each_sensors_bias_along_its_axis(hand, calibrated):
    assert calibrated["code"] == 0, calibrated["err"]
    offsets = SensorOffsets.read(calibrated["file"])
    assert offsets.grasps.tolist() == [GRASPS] * 3
    before, after = gel_shift_axes(hand["bias"]), gel_shift_axes(hand["bias"] @ offsets.offsets)
    # Measured: the gel centres 0.5-2.1 mm off along the sensors' axes before, 0.02-0.08 mm after; the contact
    # points 0.56-2.36 mm off the surface (RMS) before, 0.01-0.04 after. Sideways, on this smooth object, a tilt
    # explains the presses as well as a slide: 0.24-4.7 mm before, 0.11-2.6 after, not asserted.
    assert np.all(np.abs(after[:, 0]) < 0.25e-3) and np.all(np.abs(after[:, 0]) < 0.2 * np.abs(before[:, 0]))
    assert np.all(offsets.residual_mm < 0.2 * offsets.residual_before_mm)
    lines = calibrated["out"].splitlines()
    assert lines[0].startswith(f"sensor offsets written to {calibrated['file']}")
    for i in range(3):
        assert any(line.split()[:2] == [str(i), str(GRASPS)] for line in lines), calibrated["out"]
    assert lines[-1] == f"use: tactile6d estimate ... --sensor-offsets {calibrated['file']}"
    assert json.loads(calibrated["file"].read_text())["notes"]["object"] == OBJECT


@pytest.mark.slow
def test_estimate_and_track_read_the_corrected_poses(capsys, hand, calibrated, tmp_path):
    offsets = SensorOffsets.read(calibrated["file"])
    scene = hand["folders"][GRASPS]
    # The same scene with the corrected poses written in: what --sensor-offsets must amount to.
    corrected = tmp_path / "corrected"
    corrected.mkdir()
    for f in scene.iterdir():
        (corrected / f.name).write_bytes(f.read_bytes())
    reported = g.text_to_poses((scene / "poses_sensors.txt").read_text())
    (corrected / "poses_sensors.txt").write_text(g.poses_to_text(apply_sensor_offsets(reported, offsets)))
    common = ["--object", OBJECT, "--artifacts", str(hand["artifacts"]), "--json", *QUICK]
    code, applied, err = run(capsys, "estimate", "--scene", str(scene), "--sensor-offsets", str(calibrated["file"]),
                             *common)
    assert code == 0, err
    code, written, err = run(capsys, "estimate", "--scene", str(corrected), *common)
    assert code == 0, err
    # the same poses, but for the last bits the pose file's text round trip (axis-angle) changes
    np.testing.assert_allclose(json.loads(applied)["poses"], json.loads(written)["poses"], atol=1e-9)
    code, plain, _ = run(capsys, "estimate", "--scene", str(scene), *common)
    assert not np.allclose(json.loads(plain)["poses"][0], json.loads(applied)["poses"][0], atol=1e-4)

    # Two frames of a stream, as numbered folders.
    frames = np.stack([reported, g.text_to_poses((hand["folders"][0] / "poses_sensors.txt").read_text())])
    images = np.stack([read_scene_dir(folder)[1] for folder in (scene, hand["folders"][0])])
    sequence_dirs.write_sequence_dir(tmp_path / "reported", frames, images, np.stack([NO_CONTACT] * 3))
    sequence_dirs.write_sequence_dir(tmp_path / "fixed", apply_sensor_offsets(frames, offsets), images,
                                     np.stack([NO_CONTACT] * 3))
    track = ["track", "--object", OBJECT, "--artifacts", str(hand["artifacts"]), "--json", *QUICK]
    code, applied, err = run(capsys, *track, "--sequence", str(tmp_path / "reported"), "--sensor-offsets",
                             str(calibrated["file"]))
    assert code == 0, err
    code, written, err = run(capsys, *track, "--sequence", str(tmp_path / "fixed"))
    assert code == 0, err
    poses = [[json.loads(line)["pose"] for line in out.splitlines()] for out in (applied, written)]
    assert len(poses[0]) == 2
    np.testing.assert_allclose(poses[0], poses[1], atol=1e-9)


@pytest.mark.slow
def test_one_known_pose_for_every_grasp(capsys, hand, tmp_path):
    """A fixture holds the object where it always is: --object-pose gives it once, object_pose.txt not needed."""
    folders = []
    for k in (0, 1):  # grasp 0 twice: the object where the fixture holds it both times
        folder = tmp_path / f"g{k}"
        folder.mkdir()
        for f in hand["folders"][0].iterdir():
            if f.name != "object_pose.txt":
                (folder / f.name).write_bytes(f.read_bytes())
        folders.append(str(folder))
    pose_file = tmp_path / "fixture.txt"
    args = ["calibrate-sensors", "--object", OBJECT, "--scene", *folders, "--artifacts", str(hand["artifacts"]),
            "--out", str(tmp_path / "o.json"), *QUICK]
    code, _, err = run(capsys, *args)
    assert code == 2 and "object_pose.txt" in err and "--object-pose" in err
    pose_file.write_text((hand["folders"][0] / "object_pose.txt").read_text())
    code, out, err = run(capsys, *args, "--object-pose", str(pose_file))
    assert code == 0, err
    assert "warning: sensor 0 touched in 2 grasp(s)" in err


@pytest.mark.parametrize("content, message", [("1 2 3", "expected 7 numbers"), ("", "expected one")])
@pytest.mark.slow
def test_a_bad_object_pose_file_is_named(capsys, hand, tmp_path, content, message):
    pose_file = tmp_path / "fixture.txt"
    pose_file.write_text(content)
    code, _, err = run(capsys, "calibrate-sensors", "--object", OBJECT, "--scene", str(hand["folders"][0]),
                       "--artifacts", str(hand["artifacts"]), "--object-pose", str(pose_file), *QUICK)
    assert code == 2 and str(pose_file) in err and message in err


@pytest.mark.slow
def test_offsets_that_do_not_fit_the_scene_are_errors(capsys, hand, calibrated, tmp_path):
    common = ["estimate", "--object", OBJECT, "--artifacts", str(hand["artifacts"]), *QUICK]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "something else"}))
    code, _, err = run(capsys, *common, "--scene", str(hand["folders"][0]), "--sensor-offsets", str(bad))
    assert code == 2 and "not a sensor offsets file" in err and str(bad) in err
    data = json.loads(calibrated["file"].read_text())
    data["sensors"] = data["sensors"][:2]
    two = tmp_path / "two.json"
    two.write_text(json.dumps(data))
    code, _, err = run(capsys, *common, "--scene", str(hand["folders"][0]), "--sensor-offsets", str(two))
    assert code == 2 and "offsets for 2 sensors" in err


@pytest.mark.slow
def test_no_prior_is_an_error(capsys, hand):
    code, _, err = run(capsys, "calibrate-sensors", "--object", OBJECT, "--scene", str(hand["folders"][0]),
                       "--artifacts", str(hand["artifacts"]), "sensors.pose_sigma_mm=0", "sensors.pose_sigma_deg=0")
    assert code == 2 and "pose_sigma" in err


@pytest.mark.slow
def test_no_contact_images_estimated_from_the_grasps(capsys, hand, tmp_path):
    """``--background from-scenes`` as for ``estimate``: each sensor's no-contact image from its images in the grasps
    given (said on stderr), winning over the folders' own."""
    out = tmp_path / "offsets.json"
    code, _, err = run(capsys, "calibrate-sensors", "--object", OBJECT, "--scene", *map(str, hand["folders"][:GRASPS]),
                       "--artifacts", str(hand["artifacts"]), "--out", str(out), "--background", "from-scenes",
                       *QUICK)
    assert code == 0, err
    assert f"estimated from its images in the {GRASPS} scenes" in err
    assert "--background given, the folder's background_<i>.png are not used" in err
    assert SensorOffsets.read(out).n_sensors == 3
    code, _, err = run(capsys, "calibrate-sensors", "--object", OBJECT, "--scene", str(hand["folders"][0]),
                       "--artifacts", str(hand["artifacts"]), "--out", str(out), "--background", "from-scenes", *QUICK)
    assert code == 2 and "needs at least 5 scenes" in err


@pytest.mark.slow
def test_grasps_of_your_own_unit_are_read_against_it_given_as_a_known_unit(capsys, hand, tmp_path, data_dir,
                                                                            monkeypatch):
    """The grasps as a unit of the user's sees them, whose LEDs differ from every known unit's (the paper's unit's
    no-contact image turned half a turn), once with its no-contact images in the folders and once without: given as
    a known unit (--known-units), each image is read against it, as ``estimate`` reads it, and the offsets are those
    fitted with the folders' own no-contact images; without, the images are misread against the default one."""
    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    unit = np.ascontiguousarray(read_tactile_image(data_dir / "digit" / "caddeo2023" / "background.png")[::-1, ::-1])
    own, bare = [], []
    for k in range(GRASPS):
        for folders, with_backgrounds in ((own, True), (bare, False)):
            folder = tmp_path / ("own" if with_backgrounds else "bare") / f"grasp_{k}"
            folder.mkdir(parents=True)
            for name in ("poses_sensors.txt", "object_pose.txt"):
                (folder / name).write_bytes((hand["folders"][k] / name).read_bytes())
            for i in range(3):
                # rendered over the flat NO_CONTACT: the same presses over the user's unit
                pressed = read_tactile_image(hand["folders"][k] / f"Image_heatmap_{i}.png").astype(np.int16)
                write_tactile_image(folder / f"Image_heatmap_{i}.png",
                                    np.clip(pressed - NO_CONTACT + unit, 0, 255).astype(np.uint8))
                if with_backgrounds:
                    write_tactile_image(folder / f"background_{i}.png", unit)
            folders.append(str(folder))
    units = tmp_path / "units"
    units.mkdir()
    write_tactile_image(units / "lab_unit_7.png", unit)
    common = ["calibrate-sensors", "--object", OBJECT, "--artifacts", str(hand["artifacts"]), *QUICK]
    code, _, err = run(capsys, *common, "--scene", *own, "--out", str(tmp_path / "own.json"))
    assert code == 0, err
    code, _, err = run(capsys, *common, "--scene", *bare, "--known-units", str(units), "--out",
                       str(tmp_path / "known.json"))
    assert code == 0, err
    assert err.count("agrees with lab_unit_7's") == 3 * GRASPS, err
    known = SensorOffsets.read(tmp_path / "known.json")
    np.testing.assert_array_equal(known.offsets, SensorOffsets.read(tmp_path / "own.json").offsets)
    code, _, err = run(capsys, *common, "--scene", *bare, "--out", str(tmp_path / "plain.json"))
    assert "looks like another DIGIT unit's" in err and "lab_unit_7" not in err
    assert code == 0, err
    # Measured: read against the default no-contact image, offsets of 17-20 mm along the sensors' axes (the true
    # biases are 1.5 mm per axis), against at most 2.3 mm read against the unit's own.
    plain = SensorOffsets.read(tmp_path / "plain.json").translations_mm()
    assert np.abs(plain).max() > 5 and np.abs(known.translations_mm()).max() < 5
    code, _, err = run(capsys, *common, "--scene", *bare, "--known-units", str(units), "--background",
                       str(units / "lab_unit_7.png"))
    assert code == 2 and "give --background or --known-units, not both" in err
