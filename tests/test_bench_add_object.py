"""tactile6d bench add-object: the subdivided duck has the faces asked for and the duck's shape, and the
checkout is put back as it was, whatever add-object wrote (its run is test_own_objects.py's and
test_add_object.py's)."""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tactile6d.cli import bench_add_object as bench
from tactile6d.core.config import CONF_DIR
from tactile6d.core.errors import InputError
from tactile6d.sim.mesh_import import import_mesh


def test_the_duck_is_subdivided_to_the_faces_asked_for_keeping_its_surface(tmp_path):
    duck, _ = import_mesh(bench.DUCK, "cm", 8.0)
    fine = bench.subdivided_mesh(bench.DUCK, 20_000)
    assert 20_000 <= len(fine.faces) < 24_000
    path = tmp_path / "fine.obj"
    fine.export(path)
    imported, report = import_mesh(path, "cm", 8.0)  # what add-object checks: one closed body, no repair
    assert imported.is_watertight and report.repairs == []
    np.testing.assert_allclose(imported.bounds, duck.bounds, atol=1e-9)
    assert imported.area == pytest.approx(duck.area, rel=1e-9)


def test_the_checkout_is_put_back_and_the_objects_files_removed(tmp_path, monkeypatch, capsys):
    repo = tmp_path / "repo"
    shutil.copytree(CONF_DIR, repo / "conf")  # the real config: the bench reads its own objects
    for path, text in ((Path("params.yaml"), "own: {}\n"), (Path("dvc.lock"), "schema: '2.0'\n"),
                       (Path("dvc.yaml"), "stages: {}\n")):
        (repo / path).parent.mkdir(parents=True, exist_ok=True)
        (repo / path).write_text(text)
    with pytest.raises(InputError, match="reuses the trained autoencoder"):
        bench.main(["--repo", str(repo)])
    (repo / "artifacts" / "ae").mkdir(parents=True)
    (repo / "artifacts" / "ae" / "model.pt").write_bytes(b"model")
    before = {p: (repo / p).read_bytes() for p in bench.RESTORED}

    def fake_add_object(command, cwd):  # what add-object leaves: the entry, params, a lock entry, artifacts, records
        assert command[3:6] == ["add-object", bench.NAME, command[5]] and Path(cwd) == repo
        for path in bench.RESTORED:
            (repo / path).write_text((repo / path).read_text() + f"{bench.NAME}: added\n")
        for i, path in enumerate(bench.own_artifacts(repo, bench.NAME)):
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(f'{{"seconds": {i + 1.0}}}')
        return subprocess.CompletedProcess(command, 0)

    monkeypatch.setattr(bench.subprocess, "run", fake_add_object)
    assert bench.main(["--repo", str(repo), "--faces", "5000"]) == 0
    assert {p: (repo / p).read_bytes() for p in bench.RESTORED} == before
    assert not any(path.exists() for path in bench.own_artifacts(repo, bench.NAME))
    out = capsys.readouterr().out
    assert '"faces": ' in out.splitlines()[-1] and "prepare_own@bench_add_object 6.0 s" in out
