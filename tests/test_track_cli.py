"""``tactile6d track`` on a few generated frames of prim_box (artifacts made by the real stages): numbered scene
folders, a ROS 2 bag with TF or fixed sensor poses, the BOP CSV and pose bag it writes, and its errors; and
``tactile6d bench track`` on the same frames.

The baseline (``select.method=baseline``: every database point, no image read) keeps this fast and needs no
autoencoder; what is checked here is the command's input and output, the tracker itself in test_tracker.py."""

import contextlib
import io
import json
import re
import shutil
import warnings

import numpy as np
import pytest

from stages import prepare_object, sample_surface
from tactile6d import cli
from tactile6d.core import geometry as g
from tactile6d.data import bop, layout, rosbag_io, sequence_dirs
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.object_artifacts import load_mesh
from tactile6d.sim import sequences, surface_sampling
from tactile6d.sim.render import DigitRenderer

OBJECT = "prim_box"
F = 4  # frames
FPS = 30.0
TOPICS = ["/digit0/image", "/digit1/image", "/digit2/image"]
FRAMES = ["digit_0", "digit_1", "digit_2"]
NO_CONTACT = np.broadcast_to(np.array([120, 128, 124], np.uint8), (320, 240, 3))  # RGB; a grey one is refused
BASELINE = ["select.method=baseline", "select.N=500"]


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory):
    """prim_box's object.h5 and surface.h5 (M = 500), made by the stages' own main()."""
    root = tmp_path_factory.mktemp("artifacts")
    common = ["--object", OBJECT, f"paths.artifacts_dir={root}"]
    assert prepare_object.main(common + ["prepare.collision=hull", "prepare.n_metric_points=200"]) == 0
    assert sample_surface.main(common + ["sample.M=500"]) == 0
    return root


@pytest.fixture(scope="module")
def recording(artifacts, tmp_path_factory):
    """F frames of prim_box in a moving 3-sensor grasp, rendered, written as numbered scene folders and as a ROS 2
    bag (mcap, the sensor poses on /tf); a second bag of frame 0 three times, and its sensor poses in a file."""
    mesh = load_mesh(artifacts, OBJECT)
    points = read_artifact(layout.surface_file(artifacts, OBJECT), "surface")["points"]
    renderer = DigitRenderer.from_default_config(np.ascontiguousarray(NO_CONTACT[..., ::-1]), workers=1)

    def render(obj, T_world_object, T_world_sensors, seed):
        return np.stack([renderer.render(mesh, T_world_object, T, seed + i).image
                         for i, T in enumerate(T_world_sensors)])

    spec = sequences.SequenceSpec(n_frames=F, candidates_per_object=300, lift_probability=0.0)
    seqs = sequences.generate_sequences([OBJECT], {OBJECT: mesh}, {OBJECT: surface_sampling.sample_surface(mesh)},
                                        {OBJECT: points}, render, spec, 1, 0)
    T, images = seqs.T_world_sensors[0], seqs.images[0]
    root = tmp_path_factory.mktemp("recording")
    stamps = 100.0 + np.arange(F) / FPS
    still = np.array([0, 0, 0])
    (root / "poses_sensors.txt").write_text(g.poses_to_text(T[0]))
    return {
        "stamps": stamps,
        "sequence": sequence_dirs.write_sequence_dir(root / "sequence", T, images, fps=FPS),
        "bag": rosbag_io.write_sequence_bag(root / "bag", stamps, T, images, TOPICS, FRAMES),
        "still_bag": rosbag_io.write_sequence_bag(root / "still", 50.0 + np.arange(3) / FPS, T[still], images[still],
                                                  TOPICS, FRAMES),
        "poses_file": root / "poses_sensors.txt",
        "sequences": seqs,
    }


def run(capsys, *argv):
    code = cli.main(["track", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def json_frames(out: str) -> list[dict]:
    """The --json output's objects, one per line (a NaN, which it writes for a fit term a frame has not, as None)."""
    return [json.loads(line, parse_constant=lambda name: None) for line in out.splitlines()]


def track_json(argv: list[str]) -> list[dict]:
    """``tactile6d track --object prim_box --json ARGV`` -> its frames; stdout and stderr captured here, as capsys
    serves one test only."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(["track", "--object", OBJECT, "--json", *argv])
    assert code == 0, err.getvalue()
    return json_frames(out.getvalue())


@pytest.fixture(scope="module")
def from_sequence(artifacts, recording):
    """The --json output for the sequence folder."""
    return track_json(["--sequence", str(recording["sequence"]), "--artifacts", str(artifacts), *BASELINE])


@pytest.mark.slow
def test_a_sequence_folder_gives_one_line_per_frame(capsys, artifacts, recording, from_sequence):
    code, out, err = run(capsys, "--object", OBJECT, "--sequence", str(recording["sequence"]), "--artifacts",
                         str(artifacts), *BASELINE)
    assert code == 0, err
    lines = out.splitlines()
    assert len(lines) == F
    poses = []
    for k, line in enumerate(lines):
        fields = line.split()
        assert len(fields) == 11, line  # frame stamp mode x y z ax ay az angle confidence
        assert int(fields[0]) == k and fields[1] == f"{k / FPS:.6f}"  # frames.json has the fps
        assert fields[2] in ("redetect", "update", "hold") and fields[10] == "-"  # no confidence model
        poses.append(g.line_to_pose(" ".join(fields[3:10])))
        assert g.is_rotation(poses[-1][:3, :3])
    assert lines[0].split()[2] == "redetect"
    assert err.splitlines()[-1].startswith(f"{F} frames: ") and " 0 ambiguous;" in err.splitlines()[-1]
    # the JSON output: the same frames, modes and poses (the text has 17 significant digits)
    assert [f["frame"] for f in from_sequence] == list(range(F))
    assert [f["mode"] for f in from_sequence] == [line.split()[2] for line in lines]
    np.testing.assert_allclose(np.array([f["pose"] for f in from_sequence]), np.array(poses), rtol=0, atol=1e-12)


@pytest.mark.slow
def test_json_has_a_pose_per_frame_and_the_fit_terms(from_sequence):
    assert len(from_sequence) == F
    first = from_sequence[0]
    assert first["mode"] == "redetect" and first["reason"] == "start" and first["fit_ok"] is True
    for k, frame in enumerate(from_sequence):
        assert {"frame", "stamp", "pose", "mode", "reason", "confidence", "ambiguous", "rivals", "touching",
                "residual", "agreement", "penetration", "fit_ok", "seconds"} <= set(frame)
        assert frame["stamp"] == pytest.approx(k / FPS)
        pose = np.array(frame["pose"])
        assert pose.shape == (4, 4) and g.is_rotation(pose[:3, :3]) and np.array_equal(pose[3], [0, 0, 0, 1])
        assert frame["touching"] == [True, True, True]  # the baseline reads no image: every sensor touches
        assert frame["confidence"] is None and frame["ambiguous"] is False and frame["rivals"] == []
        assert frame["seconds"] > 0
        assert frame["reason"] in (None, "start", "request", "periodic", "fit")
    assert any(f["mode"] == "update" for f in from_sequence[1:])  # the track is followed, not re-estimated


@pytest.mark.slow
def test_json_lines_are_strict_json(artifacts, recording):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert cli.main(["track", "--object", OBJECT, "--json", "--sequence", str(recording["sequence"]),
                         "--artifacts", str(artifacts), *BASELINE]) == 0
    assert out.getvalue().count("\n") == F

    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    for line in out.getvalue().splitlines():
        json.loads(line, parse_constant=refuse)


@pytest.mark.slow
def test_a_bag_in_a_bop_csv_and_a_pose_bag_out(artifacts, recording, from_sequence, tmp_path):
    out_bag, csv = tmp_path / "poses", tmp_path / "result.csv"
    # the overrides after --frames: split off its list
    frames = track_json(["--bag", str(recording["bag"]), "--images", *TOPICS, "--frames", *FRAMES, "--artifacts",
                         str(artifacts), "--out-bag", str(out_bag), "--bop", str(csv), "--obj-id", "7", *BASELINE])
    assert [f["frame"] for f in frames] == list(range(F))
    np.testing.assert_allclose([f["stamp"] for f in frames], recording["stamps"], rtol=0, atol=1e-6)
    poses = np.array([f["pose"] for f in frames])
    # the bag holds the sequence folder's frames: the same track (the sensor poses went through quaternions)
    assert [f["mode"] for f in frames] == [f["mode"] for f in from_sequence]
    np.testing.assert_allclose(poses, [f["pose"] for f in from_sequence], rtol=0, atol=1e-6)

    with_pose = [k for k, p in enumerate(poses) if np.isfinite(p).all()]
    assert with_pose == list(range(F))  # every frame has a pose here
    stamps, bag_poses = rosbag_io.read_pose_bag(out_bag)
    assert len(bag_poses) == len(with_pose)
    np.testing.assert_allclose(bag_poses, poses[with_pose], rtol=0, atol=1e-9)
    np.testing.assert_allclose(stamps, recording["stamps"][with_pose], rtol=0, atol=1e-6)

    rows = bop.read_bop_csv(csv)
    assert len(rows) == len(with_pose)
    lines = csv.read_text().splitlines()
    assert lines[0] == bop.BOP_HEADER and len(lines) == len(rows) + 1
    for row, k, line in zip(rows, with_pose, lines[1:]):
        assert (row.scene_id, row.im_id, row.obj_id) == (0, k, 7)
        assert row.score == 1.0 and row.time == pytest.approx(frames[k]["seconds"])  # no confidence model: 1
        np.testing.assert_allclose(row.T, poses[k], rtol=0, atol=1e-12)
        R_text, t_text = line.split(",")[4:6]
        np.testing.assert_array_equal([float(v) for v in R_text.split()], poses[k][:3, :3].reshape(-1))  # row-major
        np.testing.assert_allclose([float(v) for v in t_text.split()], 1000.0 * poses[k][:3, 3], rtol=1e-15)  # mm


@pytest.mark.slow
def test_the_track_is_drawn_with_plot(capsys, artifacts, recording, tmp_path):
    png = tmp_path / "track.png"
    code, out, err = run(capsys, "--object", OBJECT, "--sequence", str(recording["sequence"]), "--artifacts",
                         str(artifacts), "--plot", str(png), *BASELINE)
    assert code == 0, err
    assert len(out.splitlines()) == F  # the lines as without it
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert (int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")) == (750, 620)


@pytest.mark.slow
def test_fixed_sensor_poses_from_a_file(artifacts, recording):
    """A bag of frame 0 three times: its sensor poses from a file (--poses) or from TF (--frames) give the same
    track, whose first frame is the sequence's first."""
    common = ["--bag", str(recording["still_bag"]), "--images", *TOPICS, "--artifacts", str(artifacts), *BASELINE]
    fixed = track_json(common + ["--poses", str(recording["poses_file"])])
    from_tf = track_json(common + ["--frames", *FRAMES])
    assert len(fixed) == len(from_tf) == 3
    assert [f["mode"] for f in fixed] == [f["mode"] for f in from_tf]
    assert fixed[0]["mode"] == "redetect"
    np.testing.assert_allclose([f["pose"] for f in fixed], [f["pose"] for f in from_tf], rtol=0, atol=1e-6)
    # the same frame again: the pose stays (within what the refinement moves it: measured 0.1 mm, 0.1 deg)
    for f in fixed[1:]:
        assert f["mode"] == "update"
        pose, first = np.array(f["pose"]), np.array(fixed[0]["pose"])
        assert np.linalg.norm(pose[:3, 3] - first[:3, 3]) < 0.001
        assert np.degrees(g.rotation_angle(pose[:3, :3], first[:3, :3])) < 1.0


@pytest.mark.parametrize(
    "argv,message",
    [(["--bag", "BAG"], "--bag needs --images"),
     (["--bag", "BAG", "--images", *TOPICS], "--bag needs the sensor poses"),
     (["--sequence", "SEQUENCE", "--frames", *FRAMES], "--images, --frames, --poses and --raw-camera-frames go with --bag"),
     (["--sequence", "SEQUENCE", "--background", "first-frames", "a.png"], "first-frames stands alone"),
     (["--sequence", "SEQUENCE", "--background-frames", "4"], "--background-frames must be at least 5")],
)
def test_usage_errors_exit_2(capsys, recording, argv, message):
    argv = [{"BAG": str(recording["bag"]), "SEQUENCE": str(recording["sequence"])}.get(a, a) for a in argv]
    with pytest.raises(SystemExit) as exited:
        cli.main(["track", "--object", OBJECT, *argv])
    out, err = capsys.readouterr()
    assert exited.value.code == 2 and out == ""
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1 and err.splitlines()[-1] == errors[0] and message in errors[0], err


@pytest.mark.parametrize(
    "change,message",
    [({"--bop": "out.csv"}, f"object {OBJECT!r} is not one of the 21 BOP YCB-V objects"),
     ({"--sequence": "/nonexistent"}, "sequence folder /nonexistent not found"),
     ({"--object": "prim_nothing"}, "unknown object 'prim_nothing'"),
     ({"track.hypotheses": "0"}, "hypotheses"),
     ({"rank.refine": "false"}, "tracking refines the last pose: it needs rank.refine")],
)
@pytest.mark.slow
def test_errors_are_one_line_and_exit_2(capsys, artifacts, recording, tmp_path, change, message):
    options = {"--object": OBJECT, "--sequence": str(recording["sequence"]), "--artifacts": str(artifacts)}
    overrides = dict(item.split("=") for item in BASELINE)
    for key, value in change.items():
        if key.startswith("--"):
            options[key] = str(tmp_path / value) if key == "--bop" else value
        else:
            overrides[key] = value
    argv = [x for kv in options.items() for x in kv] + [f"{k}={v}" for k, v in overrides.items()]
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("text,message", [(None, "not found"),
                                          ("0 0 0 1 0 0 0\n1 2\n", "line 2")])
@pytest.mark.slow
def test_a_bad_poses_file_is_one_error_line(capsys, artifacts, recording, tmp_path, text, message):
    path = tmp_path / "poses.txt"
    if text is not None:
        path.write_text(text)
    code, out, err = run(capsys, "--object", OBJECT, "--bag", str(recording["bag"]), "--images", *TOPICS,
                         "--poses", str(path), "--artifacts", str(artifacts), *BASELINE)
    assert code == 2 and out == ""
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err


def still_then(recording, n_still: int, frames: slice = slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n_still`` untouched frames (the sensors' no-contact image and noise, the hand as at frame 0), then the
    recording's ``frames`` -> sensor poses (F', 3, 4, 4), images (F', 3, 320, 240, 3), the untouched frames."""
    renderer = DigitRenderer.from_default_config(np.ascontiguousarray(NO_CONTACT[..., ::-1]), workers=1)
    seqs = recording["sequences"]
    T, images = seqs.T_world_sensors[0][frames], seqs.images[0][frames]
    still = np.array([[renderer.no_contact(seed=10 * k + i) for i in range(3)] for k in range(n_still)], np.uint8)
    still = still.reshape(n_still, *images.shape[1:])
    return np.concatenate([np.repeat(T[:1], n_still, 0), T]), np.concatenate([still, images]), still


@pytest.mark.parametrize("source", ["sequence", "bag"])
@pytest.mark.slow
def test_no_contact_images_from_the_streams_first_frames(capsys, monkeypatch, artifacts, recording, tmp_path, source):
    """``--background first-frames``: each sensor's mean over the first ``--background-frames`` frames goes with
    every frame to the tracker (those frames tracked too), and stderr says so; from a sequence folder or a bag."""
    from tactile6d.estimation.tracker import Tracker

    T, images, still = still_then(recording, 5)
    if source == "sequence":
        given = ["--sequence", str(sequence_dirs.write_sequence_dir(tmp_path / "sequence", T, images, fps=FPS))]
    else:
        bag = rosbag_io.write_sequence_bag(tmp_path / "bag", 10.0 + np.arange(len(T)) / FPS, T, images, TOPICS, FRAMES)
        given = ["--bag", str(bag), "--images", *TOPICS, "--frames", *FRAMES]
    passed, track = [], Tracker.track

    def watched(self, stream):
        return track(self, (passed.append(item[2]) or item for item in stream))

    monkeypatch.setattr(Tracker, "track", watched)
    code, out, err = run(capsys, "--object", OBJECT, *given, "--artifacts", str(artifacts),
                         "--background", "first-frames", "--background-frames", "5", *BASELINE)
    assert code == 0, err
    assert len(out.splitlines()) == 5 + F
    assert "no-contact image is its mean over the first 5 frames" in err
    learned = still.mean(axis=0).round().astype(np.uint8)
    assert len(passed) == 5 + F and all(np.array_equal(b, learned) for b in passed)


@pytest.mark.slow
def test_your_own_units_are_matched_at_the_first_frame(capsys, monkeypatch, artifacts, recording, tmp_path, data_dir):
    """``--known-units``: the recording's flat no-contact colour, a unit the data directory does not know, given as
    one of the user's; the stream, passed without no-contact images, is read against it, the warning names it, and
    the poses are those with it passed. Beside --background it is an error."""
    from test_estimator import write_tiny_autoencoder

    from tactile6d.data.hdf5 import write_tactile_image

    write_tiny_autoencoder(artifacts, 500, OBJECT)
    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    (tmp_path / "units").mkdir()
    write_tactile_image(tmp_path / "units" / "lab_flat.png", NO_CONTACT)
    common = ["--object", OBJECT, "--sequence", str(recording["sequence"]), "--artifacts", str(artifacts), "--json"]
    code, known, err = run(capsys, *common, "--known-units", str(tmp_path / "units"), "select.N=500")
    assert code == 0, err
    named = [line for line in err.splitlines() if "agrees with lab_flat's" in line]
    assert [line.split(": ")[1] for line in named] == ["image 0", "image 1", "image 2"]  # decided once
    code, given, err = run(capsys, *common, "--background", str(tmp_path / "units" / "lab_flat.png"), "select.N=500")
    assert code == 0 and "lab_flat" not in err
    assert [f["pose"] for f in json_frames(known)] == [f["pose"] for f in json_frames(given)]
    code, _, err = run(capsys, *common, "--known-units", str(tmp_path / "units"), "--background",
                       str(tmp_path / "units" / "lab_flat.png"), "select.N=500")
    assert code == 2 and "give --background or --known-units, not both" in err


@pytest.mark.parametrize("n_still,count,message", [
    (0, 5, f"the input holds {F} frames, fewer than --background-frames 5"),
    (4, 6, r"sensor \d's stream: frame 4 of the first 6 shows a contact against the others"),
])
@pytest.mark.slow
def test_first_frames_that_touch_or_are_too_few_are_one_error_line(capsys, artifacts, recording, tmp_path, n_still,
                                                                   count, message):
    T, images, _ = still_then(recording, n_still)
    folder = sequence_dirs.write_sequence_dir(tmp_path / "sequence", T, images, fps=FPS)
    code, out, err = run(capsys, "--object", OBJECT, "--sequence", str(folder), "--artifacts", str(artifacts),
                         "--background", "first-frames", "--background-frames", str(count), *BASELINE)
    assert code == 2 and out == ""
    assert err.startswith("error: ") and err.count("\n") == 1 and re.search(message, err), err


@pytest.mark.slow
def test_bench_track_times_the_sequences_artifact(capsys, artifacts, recording, tmp_path):
    """``tactile6d bench track`` on a sequences artifact of one sequence (the recording's): a line for the
    sequence, then the JSON figures over its F frames, the first a re-detection."""
    for folder in ("objects", "surfaces"):
        (tmp_path / folder).symlink_to(artifacts / folder)
    write_artifact(layout.sequences_file(tmp_path, "tracking"), "sequences", recording["sequences"].as_datasets())
    assert cli.main(["bench", "track", "--artifacts", str(tmp_path), *BASELINE, "track.read_ahead=1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"{recording['sequences'].names[0]}: {F} frames, update median ")
    figures = json.loads(lines[-1])
    assert figures["frames"] == F and figures["redetections"] >= 1 and figures["read_ahead"] == 1
    assert figures["fps_all"] > 0 and 0 < figures["update_median_ms"] <= figures["update_p90_ms"]


def test_bench_track_without_sequences_says_which_stage_makes_them(capsys, tmp_path):
    assert cli.main(["bench", "track", "--artifacts", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "tracking.h5: missing" in err and "dvc repro make_sequences" in err


def test_warnings_that_come_again_with_other_figures_are_told_once_per_image():
    from tactile6d.cli.track import warning_lines
    from tactile6d.perception.photometric import KnownUnitWarning, LightWarning, UnitWarning

    def caught(category, text):
        return warnings.WarningMessage(text, category, "f.py", 1)

    lines = warning_lines([
        caught(UnitWarning, "image 0: only 1.2 % of the image and 0.4 % of its rim agree"),
        caught(UnitWarning, "image 1: only 3.0 % of the image and 2.1 % of its rim agree"),
        caught(UnitWarning, "image 0: only 0.9 % of the image and 1.0 % of its rim agree"),
        caught(LightWarning, "image 0: its light would differ by a gain of 1.70/1.00/1.00"),
        caught(UnitWarning, "image 0: only 2.5 % of the image and 0.1 % of its rim agree"),
    ])
    assert lines == [
        "warning: image 0: only 1.2 % of the image and 0.4 % of its rim agree (3 times, the figures of the first)",
        "warning: image 1: only 3.0 % of the image and 2.1 % of its rim agree",
        "warning: image 0: its light would differ by a gain of 1.70/1.00/1.00",
    ]


def test_a_no_contact_image_of_another_unit_draws_the_hint_to_take_the_streams_own():
    from tactile6d.cli.track import hint_lines
    from tactile6d.perception.photometric import KnownUnitWarning, LightWarning, UnitWarning

    def caught(category):
        return warnings.WarningMessage(category("image 0: ..."), category, "f.py", 1)

    assert hint_lines([caught(LightWarning), caught(UnitWarning)], learned=False) == [
        "hint: a stream recorded from before the fingers touch gives each unit's own no-contact image: "
        "--background first-frames"]
    assert hint_lines([caught(UnitWarning)], learned=True) == []
    assert hint_lines([caught(LightWarning)], learned=False) == []
    # An image read against a known unit's no-contact image it agrees with is read right: no hint.
    assert hint_lines([caught(KnownUnitWarning)], learned=False) == []



@pytest.mark.slow
def test_a_frame_that_cannot_be_read_ends_the_stream_after_the_outputs_of_those_before(capsys, artifacts, recording,
                                                                                   tmp_path):
    """Frame 2's image is rotated (the camera's raw frame): frames 0 and 1 are answered, the BOP CSV, pose bag and
    figure hold them, a note says so, and the error ends the command with status 2."""
    import shutil

    from tactile6d.data.hdf5 import read_tactile_image, write_tactile_image

    sequence = shutil.copytree(recording["sequence"], tmp_path / "sequence")
    image = read_tactile_image(sequence / "000002" / "Image_heatmap_1.png")
    write_tactile_image(sequence / "000002" / "Image_heatmap_1.png", np.ascontiguousarray(np.rot90(image)))
    csv, out_bag, png = tmp_path / "r.csv", tmp_path / "poses.mcap", tmp_path / "t.png"
    code, out, err = run(capsys, "--object", OBJECT, "--sequence", str(sequence), "--artifacts", str(artifacts),
                         "--bop", str(csv), "--obj-id", "7", "--out-bag", str(out_bag), "--plot", str(png), *BASELINE)
    assert code == 2
    assert [int(line.split()[0]) for line in out.splitlines()] == [0, 1]
    lines = err.splitlines()
    assert lines[-2] == "note: stopped at the error below; --bop, --out-bag, --plot hold the 2 frames tracked before it"
    assert lines[-1].startswith("error: ") and "000002" in lines[-1] and "rotated by 90 degrees" in lines[-1]
    assert [row.im_id for row in bop.read_bop_csv(csv)] == [0, 1]
    assert out_bag.is_file() and len(rosbag_io.read_pose_bag(out_bag)[1]) == 2  # one .mcap file, as named
    assert png.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_an_output_bag_that_exists_is_refused_before_tracking(capsys, artifacts, recording, tmp_path):
    (tmp_path / "poses").mkdir()
    with pytest.raises(SystemExit) as exited:
        cli.main(["track", "--object", OBJECT, "--sequence", str(recording["sequence"]), "--artifacts", str(artifacts),
                  "--out-bag", str(tmp_path / "poses"), *BASELINE])
    out, err = capsys.readouterr()
    assert exited.value.code == 2 and out == ""
    assert err.splitlines()[-1].endswith(f"--out-bag {tmp_path / 'poses'} exists already; the poses are written to "
                                         "a new bag")


@pytest.mark.slow
def test_frames_without_stamps_get_their_number_over_fps(artifacts, recording, tmp_path):
    import shutil

    sequence = shutil.copytree(recording["sequence"], tmp_path / "sequence")
    (sequence / "frames.json").unlink()
    frames = track_json(["--sequence", str(sequence), "--artifacts", str(artifacts), "--fps", "10", *BASELINE])
    assert [f["stamp"] for f in frames] == [k / 10 for k in range(F)]


def test_help_shows_no_rest_markup(capsys):
    with pytest.raises(SystemExit):
        cli.main(["track", "--help"])
    out = capsys.readouterr().out
    assert "``" not in out and "tactile6d track: follow an object's pose over a stream of frames" in out


@pytest.mark.slow
def test_frames_streamed_at_vga_are_tracked_as_at_their_own_size(capsys, artifacts, recording, from_sequence, tmp_path):
    """The sequence's frames written at 480 x 640, each pixel repeated 2 x 2: tracked to the same poses, and the
    resizing said on one warning line for the whole stream."""
    import cv2

    vga = shutil.copytree(recording["sequence"], tmp_path / "vga")
    for path in vga.rglob("Image_heatmap_*.png"):
        cv2.imwrite(str(path), cv2.imread(str(path)).repeat(2, axis=0).repeat(2, axis=1))
    code, out, err = run(capsys, "--object", OBJECT, "--sequence", str(vga), "--artifacts", str(artifacts), "--json",
                         *BASELINE)
    assert code == 0, err
    frames = json_frames(out)
    np.testing.assert_array_equal(np.array([f["pose"] for f in frames]), np.array([f["pose"] for f in from_sequence]))
    sized = [line for line in err.splitlines() if "read resized" in line]
    assert len(sized) == 1 and sized[0].startswith("warning: ") and "is 480 wide x 640 high" in sized[0]
    assert f"({3 * F} times" in sized[0]
