import numpy as np
import pytest
import trimesh

from tactile6d.sim import meshes, surface_sampling


@pytest.fixture(scope="module", params=["prim_box", "prim_cylinder", "prim_rounded_box"])
def sampled(request):
    mesh, _ = meshes.clean_mesh(meshes.make_primitive(request.param))
    points, normals, faces = surface_sampling.sample_surface_even(mesh, 500, np.random.default_rng(0), oversample=20)
    return mesh, points, normals, faces


def distance_to_own_triangle(mesh, points, faces):
    """Reference: distance to the triangle's plane, and barycentric coordinates (all >= 0 inside).

    (trimesh.proximity.closest_point is off by up to 5e-5 m on some small triangles, so it cannot
    check a 1e-6 m bound.)"""
    tri = mesh.triangles[faces]
    plane = np.abs(np.einsum("nk,nk->n", points - tri[:, 0], mesh.face_normals[faces]))
    bary = trimesh.triangles.points_to_barycentric(tri, points)
    return plane, bary


def test_points_lie_on_the_mesh(sampled):
    mesh, points, _, faces = sampled
    plane, bary = distance_to_own_triangle(mesh, points, faces)
    assert plane.max() < 1e-6
    assert bary.min() > -1e-6 and bary.max() < 1 + 1e-6


def test_normals_are_unit_and_outward(sampled):
    mesh, points, normals, _ = sampled
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    # a step along the normal leaves the solid, a step against it enters
    assert not mesh.contains(points + 1e-4 * normals).any()
    assert mesh.contains(points - 1e-4 * normals).all()


def test_spacing_is_even(sampled):
    _, points, _, _ = sampled
    nn = surface_sampling.nearest_neighbour_distances(points)
    assert nn.min() >= 0.7 * nn.mean()


def test_fps_against_brute_force():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(200, 3))
    chosen = surface_sampling.farthest_point_sampling(pts, 20, first=5)
    naive = [5]
    for _ in range(19):
        d = np.min(np.linalg.norm(pts[:, None] - pts[naive][None], axis=2), axis=1)
        naive.append(int(np.argmax(d)))
    assert chosen.tolist() == naive


def test_random_points_are_area_weighted():
    # two triangles, one with 3x the area of the other
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [5, 0, 0], [2, 2, 0]], float)
    mesh = trimesh.Trimesh(v, [[0, 1, 2], [3, 4, 5]], process=False)
    _, face = surface_sampling.sample_surface_random(mesh, 40_000, np.random.default_rng(0))
    assert np.mean(face == 1) == pytest.approx(3.0 / 3.5, abs=0.01)  # areas 0.5 and 3


def test_ycb_sampling(data_dir):
    mesh, _ = meshes.clean_mesh(meshes.load_mesh_file(data_dir / "ycb/004_sugar_box/textured_simple.obj"))
    points, _normals, faces = surface_sampling.sample_surface_even(mesh, 300, np.random.default_rng(0), oversample=10)
    plane, bary = distance_to_own_triangle(mesh, points, faces)
    assert plane.max() < 1e-6 and bary.min() > -1e-6
    nn = surface_sampling.nearest_neighbour_distances(points)
    assert nn.min() >= 0.7 * nn.mean()
