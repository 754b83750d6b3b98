"""Stage rank on fabricated hypotheses: the same ranked poses from the stage on one process and on two workers."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from stages import rank
from tactile6d.core import geometry as g
from tactile6d.core.errors import ConfigError
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.estimation.run_storage import compact_hypotheses, stack_contacts
from tactile6d.perception.contacts import sensors_to_landmark_contacts
from tactile6d.sim.meshes import pack_pieces

SCENES = 4  # scene 2 has no hypotheses (its selection failed)
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def artifacts(tmp_path):
    mesh = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    write_artifact(layout.object_file(tmp_path, "box"), "object",
                   {"vertices": mesh.vertices, "faces": mesh.faces,
                    "metric_points": trimesh.sample.sample_surface(mesh, 400, seed=0)[0],
                    **pack_pieces([(np.asarray(mesh.vertices), np.asarray(mesh.faces))])})
    rng = np.random.default_rng(0)
    p = np.array([[0.0, 0.0, 0.025], [0.06, 0.0, 0.0], [0.0, -0.04, 0.0]])
    n = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    truths = [g.make_pose(g.random_rotations(1, rng)[0], rng.uniform(-0.1, 0.1, 3)) for _ in range(SCENES)]
    sensors = np.stack([T @ sensor_poses_touching(p, n, 0.0, 0.0018) for T in truths])
    translations, rotvecs, losses, offsets = [], [], [], [0]
    for s, T in enumerate(truths):
        k = 0 if s == 2 else 60
        # the truth, poses near it and poses far from it, with losses that do not order them
        noise = [g.make_pose(g.rotvec_to_rotmat(rng.normal(scale=0.2 if i > 20 else 0.02, size=3)),
                             rng.normal(scale=0.03 if i > 20 else 0.002, size=3)) for i in range(k)]
        poses = np.array([T @ d for d in noise]).reshape(-1, 4, 4)
        compact = compact_hypotheses(poses, rng.uniform(0.0, 0.003, k))
        translations.append(compact["translations"])
        rotvecs.append(compact["rotvecs"])
        losses.append(compact["losses"])
        offsets.append(offsets[-1] + k)
    names = np.array([f"box/scene_{s}" for s in range(SCENES)])
    write_artifact(layout.run_dir(tmp_path, "tiny", "baseline") / "hypotheses.h5", "hypotheses", {
        "names": names, "objects": np.array(["box"] * SCENES), "T_world_sensors": sensors,
        "failure": np.array(["", "", "no tuple", ""]),
        **stack_contacts([sensors_to_landmark_contacts(T) for T in sensors], 3),
        "translations": np.concatenate(translations), "rotvecs": np.concatenate(rotvecs),
        "losses": np.concatenate(losses), "tuple_index": np.zeros(offsets[-1], np.int32),
        "offsets": np.array(offsets), "seconds_encode": np.zeros(SCENES), "seconds_select": np.zeros(SCENES),
        "seconds_optimize": np.zeros(SCENES)})
    return tmp_path, np.stack(truths)


def _rank(artifacts, workers):
    """The stage as the pipeline runs it: its own process, whose libraries ``stages`` caps at AVX2 before they
    load. This test process cannot be capped (NumPy is loaded), and on an AVX-512 machine its NumPy and
    OpenBLAS round other last bits than the capped worker processes do."""
    done = subprocess.run([sys.executable, "-m", "stages.rank", "--scene-set", "tiny", "--method", "baseline",
                           f"paths.artifacts_dir={artifacts}", f"executor.workers={workers}"],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return read_artifact(layout.run_dir(artifacts, "tiny", "baseline") / "ranked.h5", "ranked")


@pytest.mark.slow
def test_two_workers_rank_as_one_process_and_skip_a_scene_without_hypotheses(artifacts):
    path, truths = artifacts
    one = {k: np.asarray(v) for k, v in _rank(path, 1).data.items()}
    two = _rank(path, 2)
    for key, value in one.items():
        if key != "seconds_rank":
            np.testing.assert_array_equal(np.asarray(two[key]), value, err_msg=key)
    assert list(one["n_poses"]) == [5, 5, 0, 5]
    assert np.isnan(one["poses"][2]).all() and one["seconds_rank"][2] == 0.0
    assert (np.asarray(two["seconds_rank"])[[0, 1, 3]] > 0).all()
    # the best pose is one of the poses near the truth
    for s in (0, 1, 3):
        assert np.linalg.norm(one["poses"][s, 0, :3, 3] - truths[s, :3, 3]) < 0.02


def test_workers_below_one_are_refused(artifacts):
    with pytest.raises(ConfigError, match="executor.workers"):
        rank.main(["--scene-set", "tiny", "--method", "baseline", f"paths.artifacts_dir={artifacts[0]}",
                   "executor.workers=0"])
