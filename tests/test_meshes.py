import numpy as np
import pytest
import trimesh

from tactile6d.core.errors import MeshError
from tactile6d.sim import meshes


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


def test_collision_fidelity_of_exact_and_loose_pieces():
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    rng = np.random.default_rng(0)
    exact = meshes.collision_fidelity(box, [(box.vertices, box.faces)], 50_000, rng)
    assert exact["excess"] < 0.01 and exact["missing"] < 0.01
    loose = trimesh.creation.box(extents=(0.11, 0.06, 0.04))  # 10 % too long
    fid = meshes.collision_fidelity(box, [(loose.vertices, loose.faces)], 50_000, rng)
    assert fid["excess"] == pytest.approx(0.1, abs=0.02)


@pytest.mark.slow
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


# ---- procedural shapes (the identification library's distractors) ---------------------------------

@pytest.mark.parametrize("name,expected", [("shape_0", True), ("shape_17", True), ("shape_017", False),
                                           ("shape_-1", False), ("shape_", False), ("shape_1x", False),
                                           ("prim_box", False)])
def test_procedural_names(name, expected):
    assert meshes.is_procedural(name) is expected
    assert meshes.is_primitive(name) is (expected or name in meshes.PRIMITIVE_NAMES)


@pytest.mark.slow
def test_procedural_shapes_are_reproducible_closed_and_of_ycb_like_size():
    kinds = set()
    for k in range(40):
        kind, extents, mesh = meshes.procedural_shape(k)
        again = meshes.make_primitive(f"shape_{k}")
        np.testing.assert_array_equal(meshes.make_primitive(f"shape_{k}").vertices, again.vertices)
        cleaned, report = meshes.clean_mesh(again)
        assert report["watertight"], (k, kind)
        # the extents are those reported, longest along x, within a YCB object's range
        np.testing.assert_allclose(cleaned.extents, extents, atol=1e-9)
        assert 0.06 * 0.99 <= extents[0] <= 0.22 and extents[0] == extents.max() and extents.min() >= 0.015, (k, extents)
        kinds.add(kind)
    assert kinds == set(meshes.PROCEDURAL_KINDS)


def test_an_unknown_name_lists_the_procedural_ones():
    with pytest.raises(MeshError, match="shape_<k>"):
        meshes.make_primitive("prim_teapot")


def test_points_in_a_finely_tessellated_hull_are_tested_in_blocks(monkeypatch):
    """A sphere's 20 480-face hull against points tested a few faces' worth at a time: the same answer
    as the distance from the centre (the hull's inscribed and circumscribed radii bound the ambiguity)."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.04)
    monkeypatch.setattr(meshes, "_HALF_SPACE_BLOCK", 3 * len(sphere.faces))  # 3 points per block
    points = np.random.default_rng(0).uniform(-0.05, 0.05, (400, 3))
    r = np.linalg.norm(points, axis=1)
    inside = meshes.points_in_convex_pieces(points, [(sphere.vertices, sphere.faces)])
    clear = np.abs(r - 0.04) > 1e-4  # the tessellation's sagitta is under 0.1 mm
    assert clear.sum() > 350
    np.testing.assert_array_equal(inside[clear], r[clear] < 0.04)
