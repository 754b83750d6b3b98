import numpy as np
import pytest
import trimesh

from tactile6d import meshes
from tactile6d.errors import MeshError


@pytest.mark.parametrize("name", meshes.PRIMITIVE_NAMES)
def test_primitives_are_clean_closed_and_outward(name):
    mesh, report = meshes.clean_mesh(meshes.make_primitive(name))
    assert report["watertight"] and mesh.volume > 0
    meshes.check_units(mesh, name)


def test_unknown_primitive():
    with pytest.raises(MeshError, match="unknown primitive"):
        meshes.make_primitive("prim_teapot")


def test_clean_merges_uv_seams_and_fixes_inward_winding():
    box = trimesh.creation.box(extents=(0.1, 0.05, 0.02))
    # split every face's vertices (as an OBJ with per-face UVs does) and wind inward
    tri = box.triangles.reshape(-1, 3)
    split = trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3)[:, ::-1], process=False)
    assert not split.is_watertight
    mesh, report = meshes.clean_mesh(split)
    assert report["watertight"] and len(mesh.vertices) == 8
    assert mesh.volume == pytest.approx(0.1 * 0.05 * 0.02)


def test_units(tmp_path):
    big = trimesh.creation.box(extents=(100.0, 60.0, 40.0))  # a box in millimetres
    with pytest.raises(MeshError, match="millimetres"):
        meshes.check_units(big, "box")
    with pytest.warns(UserWarning, match="outside"):
        meshes.check_units(trimesh.creation.box(extents=(0.1, 0.1, 0.002)), "sheet")


def test_degenerate_and_missing_meshes(tmp_path):
    flat = trimesh.Trimesh(np.zeros((3, 3)), [[0, 1, 2]], process=False)
    with pytest.raises(MeshError, match="degenerate"):
        meshes.clean_mesh(flat)
    with pytest.raises(MeshError, match="not found"):
        meshes.load_mesh_file(tmp_path / "none.obj")
    junk = tmp_path / "junk.obj"
    junk.write_text("this is not a mesh\n")
    with pytest.raises(MeshError):
        meshes.load_mesh_file(junk)


def test_pack_unpack_pieces():
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.icosphere(subdivisions=1)
    pieces = [(a.vertices, a.faces), (b.vertices, b.faces)]
    back = meshes.unpack_pieces(meshes.pack_pieces(pieces))
    for (v0, f0), (v1, f1) in zip(pieces, back):
        np.testing.assert_array_equal(v0, v1)
        np.testing.assert_array_equal(f0, f1)


def test_collision_fidelity_of_exact_and_loose_pieces():
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    rng = np.random.default_rng(0)
    exact = meshes.collision_fidelity(box, [(box.vertices, box.faces)], 50_000, rng)
    assert exact["excess"] < 0.01 and exact["missing"] < 0.01
    loose = trimesh.creation.box(extents=(0.11, 0.06, 0.04))  # 10 % too long
    fid = meshes.collision_fidelity(box, [(loose.vertices, loose.faces)], 50_000, rng)
    assert fid["excess"] == pytest.approx(0.1, abs=0.02)


def test_coacd_pieces_cover_an_l_shape():
    l_shape = trimesh.util.concatenate(
        [trimesh.creation.box(extents=(0.1, 0.02, 0.02)),
         trimesh.creation.box(extents=(0.02, 0.1, 0.02), transform=trimesh.transformations.translation_matrix((-0.04, 0.04, 0)))]
    )
    l_shape = trimesh.boolean.union([l_shape.split()[0], l_shape.split()[1]], engine="manifold")
    pieces = meshes.convex_pieces_coacd(l_shape, threshold=0.05, max_pieces=8, seed=0)
    fid = meshes.collision_fidelity(l_shape, pieces, 50_000, np.random.default_rng(1))
    hull = meshes.collision_fidelity(l_shape, [(l_shape.convex_hull.vertices, l_shape.convex_hull.faces)], 50_000,
                                     np.random.default_rng(1))
    assert len(pieces) >= 2 and fid["excess"] < 0.15 < hull["excess"]


def test_ycb_marker_is_handled(data_dir):
    mesh = meshes.load_mesh_file(data_dir / "ycb/040_large_marker/textured_simple.obj")
    clean, report = meshes.clean_mesh(mesh)
    assert not report["watertight"]  # non-manifold seams stay; see clean_mesh
    assert report["faces"] < report["faces_in"]  # duplicate faces were dropped
    assert 2.0e-5 < clean.volume < 3.5e-5
