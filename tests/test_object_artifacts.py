"""data.object_artifacts: every per-object loader, one cache, and the missing-file hint."""

import os

import numpy as np
import pytest
import trimesh

from tactile6d.core.errors import ArtifactError
from tactile6d.data import layout
from tactile6d.data import object_artifacts as oa
from tactile6d.data.hdf5 import write_artifact
from tactile6d.sim import meshes


def _write_object(artifacts, name, size=0.05):
    box, ball = trimesh.creation.box(extents=(size, size, size)), trimesh.creation.icosphere(subdivisions=1)
    pieces = [(box.vertices, box.faces), (0.01 * ball.vertices, ball.faces)]
    path = layout.object_file(artifacts, name)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_artifact(path, "object", {"vertices": box.vertices, "faces": box.faces, "metric_points": box.vertices[:4],
                                    **meshes.pack_pieces(pieces)})
    return box, pieces


@pytest.fixture(autouse=True)
def fresh_cache():
    oa.clear_cache()
    yield
    oa.clear_cache()


def test_the_loaders_give_back_what_prepare_object_stored(tmp_path):
    box, pieces = _write_object(tmp_path, "cube")
    for (vertices, _), loaded in zip(pieces, oa.load_collision_vertices(tmp_path, "cube"), strict=True):
        np.testing.assert_array_equal(vertices, loaded)
    mesh = oa.load_mesh(tmp_path, "cube")
    np.testing.assert_array_equal(mesh.vertices, box.vertices)
    np.testing.assert_array_equal(mesh.faces, box.faces)
    np.testing.assert_array_equal(oa.load_metric_points(tmp_path, "cube"), box.vertices[:4])


def test_a_file_is_read_once_shared_read_only_and_read_again_once_remade(tmp_path):
    _write_object(tmp_path, "cube", size=0.05)
    first = oa.load_metric_points(tmp_path, "cube")
    assert oa.load_metric_points(tmp_path, "cube") is first  # the cache's own array, not a new read
    with pytest.raises(ValueError):
        first[0, 0] = 1.0  # shared by every caller: read-only
    _write_object(tmp_path, "cube", size=0.08)
    path = layout.object_file(tmp_path, "cube")
    os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 10**9))  # a later stage run
    again = oa.load_metric_points(tmp_path, "cube")
    assert np.abs(again).max() == pytest.approx(0.04)


def test_a_missing_file_names_the_stage_that_makes_it(tmp_path):
    with pytest.raises(ArtifactError, match=r"dvc repro prepare_object@mug"):
        oa.load_mesh(tmp_path, "mug")
    with pytest.raises(ArtifactError, match=r"dvc repro encode_database@mug"):
        oa.load_database_angles(tmp_path, "mug")
    with pytest.raises(ArtifactError, match=r"dvc repro sample_distractors\b"):
        oa.load_surface_points(layout.distractors_dir(tmp_path), "prim_box")
    with pytest.raises(ArtifactError, match=r"dvc repro prepare_own@duck\b"):
        oa.load_mesh(layout.own_dir(tmp_path), "duck")


def test_a_misspelt_object_gets_the_name_it_is_close_to(tmp_path):
    _write_object(tmp_path, "004_sugar_box")
    _write_object(tmp_path, "036_wood_block")
    with pytest.raises(ArtifactError, match=r"objects/004_sugarbox.h5: missing \(did you mean '004_sugar_box'\? "
                                            r".*objects has 2: 004_sugar_box, 036_wood_block\); make it with "
                                            r"`dvc repro prepare_object@004_sugarbox`"):
        oa.load_mesh(tmp_path, "004_sugarbox")
    with pytest.raises(ArtifactError, match=r"objects/mug.h5: missing; make it"):  # nothing close: no guess
        oa.load_mesh(tmp_path, "mug")


def test_an_artifacts_directory_that_does_not_exist_is_named(tmp_path):
    for folder in (tmp_path / "nowhere", layout.distractors_dir(tmp_path / "nowhere")):
        with pytest.raises(ArtifactError, match=r"nowhere: no such artifacts directory; make the artifacts with "
                                                r"`make reproduce`"):
            oa.load_surface_points(folder, "004_sugar_box")
