"""tactile6d add-object: a mesh checked before anything is written, the entry added to conf/own with its header
kept, params.yaml refreshed; the DVC run itself is the four stages' (test_own_objects.py runs their code)."""

import shutil
from pathlib import Path

import pybullet_data
import pytest
import trimesh

from tactile6d.cli import add_object
from tactile6d.core.config import CONF_DIR, compose_config
from tactile6d.core.errors import InputError, MeshError
from tactile6d.sim.mesh_import import MeshSource, own_objects

BUNNY = Path(pybullet_data.getDataPath()) / "bunny.obj"


@pytest.fixture
def checkout(tmp_path):
    repo = tmp_path / "repo"
    shutil.copytree(CONF_DIR, repo / "conf")
    (repo / "dvc.yaml").write_text("stages: {}\n")
    return repo


@pytest.mark.slow
def test_the_entry_is_added_with_the_header_kept_and_params_refreshed(checkout, capsys):
    before = (checkout / add_object.OWN_FILE).read_text()
    header = "".join(line for line in before.splitlines(keepends=True) if line.startswith("#"))
    assert before.startswith(header)  # the header comment is the file's first lines
    assert add_object.main(["bunny", str(BUNNY), "--units", "cm", "--scale", "5", "--repo", str(checkout),
                            "--no-run"]) == 0
    out = capsys.readouterr().out
    assert "bunny: 902 faces" in out and "dvc repro prepare_own@bunny sample_own@bunny render_own@bunny " \
                                         "encode_own@bunny" in out
    assert (checkout / add_object.OWN_FILE).read_text().startswith(header)
    cfg = compose_config(conf_dir=checkout / "conf")
    assert own_objects(cfg) == {**own_objects(compose_config()),  # the entries there before are kept
                                "bunny": MeshSource("bunny", BUNNY, "cm", 5.0, (0.0, 0.0, 0.0))}
    assert "bunny:" in (checkout / "params.yaml").read_text()
    # the same name again: refused, unless replaced
    with pytest.raises(InputError, match="'bunny' is already in"):
        add_object.main(["bunny", str(BUNNY), "--units", "cm", "--repo", str(checkout), "--no-run"])
    assert add_object.main(["bunny", str(BUNNY), "--units", "cm", "--scale", "4", "--repo", str(checkout),
                            "--no-run", "--replace"]) == 0
    assert own_objects(compose_config(conf_dir=checkout / "conf"))["bunny"].scale == 4.0


@pytest.mark.slow
def test_a_mesh_inside_the_checkout_is_stored_relative_to_it(checkout):
    (checkout / "meshes").mkdir()
    shutil.copy(BUNNY, checkout / "meshes" / "bunny.obj")
    assert add_object.main(["bunny", str(checkout / "meshes" / "bunny.obj"), "--units", "cm", "--repo",
                            str(checkout), "--no-run"]) == 0
    assert own_objects(compose_config(conf_dir=checkout / "conf"))["bunny"].mesh == Path("meshes/bunny.obj")


def test_a_bad_mesh_is_refused_before_anything_is_written(checkout, tmp_path):
    before = (checkout / add_object.OWN_FILE).read_text()
    two = trimesh.util.concatenate([trimesh.creation.box((0.05, 0.05, 0.05)),
                                    trimesh.creation.box((0.05, 0.05, 0.05)).apply_translation((0.2, 0, 0))])
    two.export(tmp_path / "two.stl")
    (tmp_path / "notes.obj").write_text("not a mesh\n")
    for mesh, units, message in ((tmp_path / "two.stl", "m", "bodies"), (BUNNY, "m", "wrong units"),
                                 (tmp_path / "notes.obj", "mm", "")):
        with pytest.raises(MeshError, match=message):
            add_object.main(["part", str(mesh), "--units", units, "--repo", str(checkout), "--no-run"])
    assert (checkout / add_object.OWN_FILE).read_text() == before and not (checkout / "params.yaml").exists()


def test_outside_a_checkout_it_says_so(tmp_path):
    with pytest.raises(InputError, match="is not a tactile6d checkout"):
        add_object.main(["bunny", str(BUNNY), "--units", "cm", "--repo", str(tmp_path), "--no-run"])


def test_the_targets_and_the_dvc_it_runs(checkout):
    assert add_object.dvc_targets("mug") == ["prepare_own@mug", "sample_own@mug", "render_own@mug", "encode_own@mug"]
    assert add_object.dvc_command(checkout)[1:] == ["-m", "dvc"]
    (checkout / "scripts").mkdir()
    (checkout / "scripts" / "dvc_fast_lock.py").write_text("")
    assert add_object.dvc_command(checkout)[1] == str(checkout / "scripts" / "dvc_fast_lock.py")
    assert add_object.stage_times(checkout, "mug") == [(t, None) for t in add_object.dvc_targets("mug")]
