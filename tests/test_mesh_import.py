"""sim.mesh_import: a user's mesh file read in its units, each bad mesh refused with one clear error or
repaired with the repair reported."""

import numpy as np
import pytest
import trimesh

from tactile6d.core.errors import MeshError
from tactile6d.sim import mesh_import as mi


def _save(mesh, path):
    mesh.export(path)
    return path


def test_a_cad_file_in_millimetres(tmp_path):
    path = _save(trimesh.creation.box(extents=(80, 60, 40)), tmp_path / "part.stl")
    mesh, report = mi.import_mesh(path, "mm", offset=(0.0, 0.0, 0.01))
    np.testing.assert_allclose(mesh.extents, [0.08, 0.06, 0.04])
    np.testing.assert_allclose(mesh.bounds.mean(axis=0), [0.0, 0.0, 0.01], atol=1e-12)
    assert mesh.is_watertight and mesh.volume > 0
    assert report.repairs == [] and report.faces == report.faces_in == 12


@pytest.mark.parametrize("size,units,message", [
    (2000.0, "mm", r"longest side is 2 m, outside 5 mm-1.5 m: wrong units\?"),
    (0.5, "mm", r"longest side is 0.5 mm, outside 5 mm-1.5 m: wrong units\? Declared as 'm' it would be 50 cm$"),
    (120.0, "m", r"longest side is 120 m, outside 5 mm-1.5 m: wrong units\? Declared as 'mm' it would be 12 cm$"),
])
def test_units_that_give_an_implausible_object_are_refused(tmp_path, size, units, message):
    path = _save(trimesh.creation.box(extents=(size, size / 2, size / 3)), tmp_path / "box.stl")
    with pytest.raises(MeshError, match=message):
        mi.import_mesh(path, units)


def test_unknown_units_and_files_that_are_not_meshes(tmp_path):
    path = _save(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), tmp_path / "box.ply")
    with pytest.raises(MeshError, match="units 'furlong' unknown; one of m, cm, mm, in"):
        mi.import_mesh(path, "furlong")
    text = tmp_path / "notes.obj"
    text.write_text("this is not a mesh\n")
    with pytest.raises(MeshError, match="notes.obj"):
        mi.import_mesh(text, "m")
    with pytest.raises(MeshError, match="not found"):
        mi.import_mesh(tmp_path / "missing.stl", "m")


def test_degenerate_and_duplicate_faces_are_dropped_and_reported(tmp_path):
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    faces = np.vstack([box.faces, box.faces[:2], [[0, 0, 1], [1, 1, 2]]])  # 2 duplicates, 2 of zero area
    path = _save(trimesh.Trimesh(box.vertices, faces, process=False), tmp_path / "box.obj")
    mesh, report = mi.import_mesh(path, "m")
    assert len(mesh.faces) == 12 and mesh.is_watertight
    assert "dropped 2 degenerate faces" in report.repairs and "dropped 2 duplicate faces" in report.repairs


def test_a_hole_is_closed_and_reported(tmp_path):
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    path = _save(trimesh.Trimesh(box.vertices, box.faces[1:], process=False), tmp_path / "open.obj")
    mesh, report = mi.import_mesh(path, "m")
    assert mesh.is_watertight and mesh.volume == pytest.approx(0.1 * 0.06 * 0.04)
    assert "closed its holes (trimesh.repair.fill_holes)" in report.repairs


def test_a_surface_that_cannot_be_closed_is_refused(tmp_path):
    # Three of a box's twelve triangles missing: a hole of five edges, which fill_holes does not close.
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    path = _save(trimesh.Trimesh(box.vertices, box.faces[3:], process=False), tmp_path / "holed.obj")
    with pytest.raises(MeshError, match=r"holed.obj: the surface is not closed and filling its holes does not close "
                                        r"it \(5 edges bound one face only or more than two\)"):
        mi.import_mesh(path, "m")


def test_scan_debris_is_dropped_but_two_bodies_are_refused(tmp_path):
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    speck = trimesh.creation.icosphere(subdivisions=1, radius=0.001)
    speck.apply_translation([0.2, 0.0, 0.0])
    mesh, report = mi.import_mesh(_save(trimesh.util.concatenate([box, speck]), tmp_path / "scan.ply"), "m")
    assert len(mesh.faces) == 12 and any(r.startswith("dropped 1 loose piece") for r in report.repairs)
    other = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    other.apply_translation([0.3, 0.0, 0.0])
    with pytest.raises(MeshError, match=r"two.ply: 2 separate bodies \(their shares of the surface: \d+ %, \d+ %\)"):
        mi.import_mesh(_save(trimesh.util.concatenate([box, other]), tmp_path / "two.ply"), "m")


def test_a_mesh_wound_inward_is_turned_outward(tmp_path):
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    path = _save(trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False), tmp_path / "inside_out.obj")
    mesh, report = mi.import_mesh(path, "m")
    assert mesh.volume > 0 and "turned its faces outward" in report.repairs
