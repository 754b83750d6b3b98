"""``tactile6d estimate`` on a scene folder, with artifacts made by the real stages for a primitive."""

import json

import numpy as np
import pytest

from stages import prepare_object, sample_surface
from tactile6d import cli
from tactile6d import geometry as g
from tactile6d import layout
from tactile6d.io import read_artifact, write_tactile_image
from tactile6d.sensor import sensor_poses_touching

T_TRUE = g.make_pose(g.rotvec_to_rotmat(np.array([0.2, 0.5, -0.4])), [0.1, 0.0, 0.2])


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory):
    """prim_box's object.h5 and surface.h5 (M = 500), made by the stages' own main()."""
    root = tmp_path_factory.mktemp("artifacts")
    common = ["--object", "prim_box", f"paths.artifacts_dir={root}"]
    assert prepare_object.main(common + ["prepare.collision=hull", "prepare.n_metric_points=200"]) == 0
    assert sample_surface.main(common + ["sample.M=500"]) == 0
    return root


@pytest.fixture(scope="module")
def scene(artifacts, tmp_path_factory):
    """A triplet folder: three sensors touching database points on three faces of the box."""
    surface = read_artifact(layout.surface_file(artifacts, "prim_box"), "surface")
    points, normals = surface["points"], surface["normals"]
    picks = [int(np.argmin(np.linalg.norm(points - t, axis=1) + 10 * np.linalg.norm(normals - n, axis=1)))
             for t, n in [((0.05, 0.01, 0.0), (1, 0, 0)), ((0.0, -0.03, 0.01), (0, -1, 0)), ((0.02, 0.0, 0.02), (0, 0, 1))]]
    T_world_sensors = T_TRUE @ sensor_poses_touching(points[picks], normals[picks], [0.1, 1.0, -2.0], 0.002)
    folder = tmp_path_factory.mktemp("scene")
    (folder / "poses_sensors.txt").write_text(g.poses_to_text(T_world_sensors))
    for i in range(3):
        write_tactile_image(folder / f"Image_heatmap_{i}.png", np.full((320, 240, 3), 100, np.uint8))
    return folder


def run(capsys, *argv):
    code = cli.main(["estimate", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_prints_the_best_pose_line_then_a_summary(capsys, artifacts, scene):
    code, out, err = run(capsys, "--object", "prim_box", "--scene", str(scene), "--artifacts", str(artifacts),
                         "select.method=baseline", "select.N=1000")
    assert code == 0, err
    lines = out.splitlines()
    best = g.line_to_pose(lines[0])
    assert g.is_rotation(best[:3, :3])
    assert any(line.startswith("baseline: |Omega_i| 500, 500, 500") for line in lines)
    assert any(line.startswith("time: encode") and "total" in line for line in lines)


def test_json_has_the_top_k_poses_scores_and_timings(capsys, artifacts, scene):
    code, out, err = run(capsys, "--object", "prim_box", "--scene", str(scene), "--artifacts", str(artifacts),
                         "--top", "3", "--json", "select.method=baseline", "select.N=1000", "select.delta_d_start=0.004")
    assert code == 0, err
    result = json.loads(out)
    assert 1 <= len(result["poses"]) <= 3 and np.asarray(result["poses"]).shape[1:] == (4, 4)
    assert len(result["scores"]) == len(result["poses"])
    assert set(result["seconds"]) == {"encode", "select", "optimize", "rank", "total"}
    assert result["selection"]["n_tuples"] <= 1000
    np.testing.assert_allclose(g.line_to_pose(result["best"]), result["poses"][0], atol=1e-9)
    # the box is symmetric, so only the fit is checked: the best pose puts the sensors on the surface
    assert result["losses"][0] < 0.003


def test_ours_runs_with_a_checkpoint_and_the_data_background(capsys, artifacts, scene, data_dir, monkeypatch):
    from test_estimator import write_tiny_autoencoder

    write_tiny_autoencoder(artifacts, 500, "prim_box")
    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    code, out, err = run(capsys, "--object", "prim_box", "--scene", str(scene), "--artifacts", str(artifacts),
                         "select.N=500")
    assert code == 0, err
    assert out.splitlines()[1].startswith("method ours, solver fast")
    assert "latent angles" in out


@pytest.mark.parametrize(
    "change,message",
    [({"--scene": "/nonexistent"}, "scene folder /nonexistent not found"),
     ({"--object": "prim_sphere"}, "dvc repro sample_surface@prim_sphere"),
     ({"select.method": "nonsense"}, "select.method must be one of ours, baseline"),
     ({"select.no_such_key": "1"}, "bad config override")],
)
def test_errors_are_one_line_and_exit_2(capsys, artifacts, scene, change, message):
    options = {"--object": "prim_box", "--scene": str(scene), "--artifacts": str(artifacts)}
    overrides = {"select.method": "baseline"}
    for key, value in change.items():
        (options if key.startswith("--") else overrides)[key] = value
    argv = [x for kv in options.items() for x in kv] + [f"{k}={v}" for k, v in overrides.items()]
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err
