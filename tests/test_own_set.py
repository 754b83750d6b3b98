"""The pipeline's own scene set (config section own_set): meshes an installed package ships, copied by stage
import_package_meshes where the default config's own entries read them, and the report's section on them.
test_own_objects.py runs make_scenes --scene-set own and evaluate_own end to end on one mesh."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pybullet_data
import pytest

from stages import import_package_meshes, report
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError
from tactile6d.data import layout
from tactile6d.sim.mesh_import import import_mesh, own_objects

PACKAGE = Path(pybullet_data.getDataPath())


@pytest.mark.slow
def test_each_packaged_mesh_is_copied_where_its_own_entry_reads_it(tmp_path):
    assert import_package_meshes.main([f"paths.artifacts_dir={tmp_path}"]) == 0
    cfg = compose_config()
    own = own_objects(cfg)
    sources = json.loads((layout.third_party_meshes_dir(tmp_path) / "sources.json").read_text())
    assert sources["package"] == "pybullet_data" and sources["version"].startswith("pybullet ")
    for name, inner in cfg.own_set.files.items():
        copy = layout.third_party_mesh_file(tmp_path, name, Path(inner).suffix)
        assert copy.read_bytes() == (PACKAGE / inner).read_bytes()
        assert sources["files"][name]["md5"] == hashlib.md5(copy.read_bytes()).hexdigest()
        # the entry reads the copy the pipeline makes (artifacts_dir is "artifacts" there)
        assert own[name].mesh == layout.third_party_mesh_file("artifacts", name, Path(inner).suffix)


def test_the_packaged_meshes_are_hand_sized_closed_bodies_as_declared():
    cfg = compose_config()
    for name, inner in cfg.own_set.files.items():
        source = own_objects(cfg)[name]
        mesh, imported = import_mesh(PACKAGE / inner, source.units, source.scale, source.offset)
        assert mesh.is_watertight and imported.repairs == [], (name, imported.repairs)
        assert 0.05 < max(imported.extents_m) < 0.2, (name, imported.extents_m)
        # the frame offset puts the origin at the centre of the object's bounds, as a YCB object's is near it
        assert np.linalg.norm(mesh.bounds.mean(axis=0)) < 0.005, name


@pytest.mark.slow
def test_a_file_the_package_lacks_is_an_error_naming_the_entry(tmp_path):
    with pytest.raises(ConfigError, match=r"own_set.files.pybullet_duck: pybullet_data has no file nope.obj"):
        import_package_meshes.main([f"paths.artifacts_dir={tmp_path}", "own_set.files.pybullet_duck=nope.obj"])
    with pytest.raises(ConfigError, match="no installed package 'not_a_package'"):
        import_package_meshes.main([f"paths.artifacts_dir={tmp_path}", "own_set.package=not_a_package"])


def test_the_report_tabulates_each_object_and_the_whole_set(tmp_path):
    cfg = compose_config()
    names = list(cfg.own_set.files)
    library = [*cfg.objects.names, *cfg.identify.distractors, *names]
    confusion = np.zeros((len(library), len(library)), dtype=int)
    for k, name in enumerate(names):
        i = library.index(name)
        confusion[i, i] = 4 if k else 2  # the first object: 2 of its 5 scenes identified first
        confusion[i, 0] = 1 if k else 3
    metrics = {
        "n_scenes": 20,
        "meshes": {n: {"units": "cm", "scale": 8.0, "faces": 1000 + k, "extents_m": [0.1, 0.05, 0.12]}
                   for k, n in enumerate(names)},
        "estimate": {**{n: {"pos_err_cm_top1": 0.1 * (k + 1), "adi_auc_paper_top1": 95.0} for k, n in enumerate(names)},
                     "average": {"pos_err_cm_top1": 0.25, "pos_err_cm_top1_median": 0.2, "adi_auc_paper_top1": 95.0}},
        "identify": {"objects": library, "confusion": confusion.tolist(), "top1": 14 / 20,
                     "top1_by_object": {n: (4 if k else 2) / 5 for k, n in enumerate(names)}},
    }
    (tmp_path / "metrics").mkdir()
    layout.metrics_file(tmp_path, "own").write_text(json.dumps(metrics))
    lines = report.own_objects_section(str(tmp_path), cfg)
    table = "\n".join(lines)
    assert f"against the whole library of {len(library)} objects" in table
    first = next(line for line in lines if line.startswith(f"| `{names[0]}` |"))
    cells = [c.strip() for c in first.strip("|").split("|")]
    assert cells[1] == f"`{cfg.own_set.files[names[0]]}`, cm x 8" and cells[2] == "1000, 10.0 x 5.0 x 12.0"
    assert cells[3:] == ["5", "0.10", "-", "95.00", "40"]
    assert next(line for line in lines if line.startswith("| **all** |")).endswith("| 20 | 0.25 | 0.20 | 95.00 | 70 |")
    assert report.own_objects_section(str(tmp_path / "none"), cfg) == ["(not run)", ""]
