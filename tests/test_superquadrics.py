from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf
from scipy.special import beta

from tactile6d.core import sensor
from tactile6d.core.errors import ConfigError
from tactile6d.sim import superquadrics as sq

CONF = Path(__file__).resolve().parent.parent / "conf" / "training_set" / "default.yaml"

# Coarser than the defaults so that the tests stay fast; the properties checked do not depend on it.
EDGE, TURN = 0.002, 0.1

SHAPES = [
    sq.Superquadric(0.05, 0.05, 0.05, 1.0, 1.0),  # sphere
    sq.Superquadric(0.06, 0.02, 0.03, 1.0, 1.0),  # ellipsoid
    sq.Superquadric(0.04, 0.03, 0.02, 0.05, 0.05),  # box
    sq.Superquadric(0.08, 0.015, 0.04, 0.1, 0.6),  # rounded prism
    sq.Superquadric(0.03, 0.05, 0.02, 1.5, 0.3),  # ridged
]


def analytic_volume(s):
    """Jaklic et al.: V = 2 a b c e1 e2 B(e1/2 + 1, e1) B(e2/2, e2/2)."""
    return 2 * s.a * s.b * s.c * s.e1 * s.e2 * beta(s.e1 / 2 + 1, s.e1) * beta(s.e2 / 2, s.e2 / 2)


@pytest.fixture(scope="module")
def meshes():
    return [sq.superquadric_mesh(s, EDGE, TURN) for s in SHAPES]


def test_mesh_is_watertight_outward_and_on_the_surface(meshes):
    for s, mesh in zip(SHAPES, meshes):
        assert mesh.is_watertight and mesh.is_winding_consistent, s
        np.testing.assert_allclose(sq.inside_outside(s, mesh.vertices), 1.0, atol=1e-9)
        assert mesh.volume == pytest.approx(analytic_volume(s), rel=0.01)
        # vertex normals are unit, outward (convex shape around the origin) and agree with the winding
        n = mesh.vertex_normals
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
        assert np.all(np.sum(n * mesh.vertices, axis=1) > 0)
        # (exponents above 1 put a bend of unbounded curvature on the ridges, hence 2.5 turns, not 2)
        face_vs_vertex = np.einsum("fk,fvk->fv", mesh.face_normals, n[mesh.faces])
        assert np.all(face_vs_vertex > np.cos(2.5 * TURN)), s


def test_normals_are_the_gradient_of_the_inside_outside_function():
    rng = np.random.default_rng(0)
    for s in SHAPES:
        p = sq.project_to_surface(s, rng.normal(size=(200, 3)))
        h = 1e-7
        grad = np.stack(
            [(sq.inside_outside(s, p + h * d) - sq.inside_outside(s, p - h * d)) / (2 * h) for d in np.eye(3)],
            axis=1,
        )
        grad /= np.linalg.norm(grad, axis=1, keepdims=True)
        np.testing.assert_allclose(sq.surface_normals(s, p), grad, atol=1e-4)


def test_mesh_resolves_faces_and_edges(meshes):
    for s, mesh in zip(SHAPES, meshes):
        assert mesh.edges_unique_length.max() < 1.5 * EDGE
        if max(s.e1, s.e2) <= 1.0:  # above 1 the ridges bend with unbounded curvature: nothing to resolve
            turn = sq._normal_angle(*np.moveaxis(mesh.vertex_normals[mesh.edges_unique], 1, 0))
            assert turn.max() < 2.5 * TURN  # a quad's diagonal spans one turn each way
    # a 20 x 30 mm gel pressed on the box's top face sees a well-resolved patch
    top = meshes[2].vertices
    under_gel = (np.abs(top[:, 0]) < 0.010) & (np.abs(top[:, 1]) < 0.015) & (top[:, 2] > 0.0199)
    assert under_gel.sum() >= (20 / 2) * (30 / 2) / 2


def test_unit_exponents_and_equal_axes_give_a_sphere(meshes):
    r = np.linalg.norm(meshes[0].vertices, axis=1)
    np.testing.assert_allclose(r, 0.05, rtol=1e-12)
    np.testing.assert_allclose(meshes[0].vertex_normals, meshes[0].vertices / r[:, None], atol=1e-12)


def test_small_exponents_give_a_box(meshes):
    s, box = SHAPES[2], meshes[2]
    np.testing.assert_allclose(box.bounds, [[-0.04, -0.03, -0.02], [0.04, 0.03, 0.02]], atol=1e-9)
    assert box.volume == pytest.approx(8 * s.a * s.b * s.c, rel=0.03)
    # most of the surface is flat, with normals along the axes
    axis_aligned = np.max(np.abs(box.face_normals), axis=1) > 0.999
    assert box.area_faces[axis_aligned].sum() > 0.8 * box.area


def test_kinds_and_biased_sampling(meshes):
    rng = np.random.default_rng(1)
    _, _, kinds = sq.sample_surface_contacts(SHAPES[0], meshes[0], 300, rng, 0.3, 0.15, 0.008)
    assert np.all(kinds == sq.SURFACE)  # a 50 mm sphere has no edges
    _, _, kinds = sq.sample_surface_contacts(SHAPES[2], meshes[2], 2000, rng, 0.3, 0.15, 0.008)
    share = np.bincount(kinds, minlength=3) / len(kinds)
    assert share[sq.EDGE] > 0.3 and share[sq.CORNER] > 0.12 and share[sq.SURFACE] > 0.3
    with pytest.raises(ConfigError):
        sq.sample_surface_contacts(SHAPES[2], meshes[2], 10, rng, 0.7, 0.5, 0.008)
    # a point takes the kind of its nearest vertex: each vertex its own
    np.testing.assert_array_equal(sq.nearest_vertex_kinds(meshes[2], meshes[2].vertices, 0.008),
                                  sq.vertex_kinds(meshes[2], 0.008))


def test_shapes_narrower_than_the_gel_give_tips_and_rods():
    # The default training set draws semi-axes down to 5 mm so that, like the marker's tip and body,
    # some shapes bend tighter than sharp_radius everywhere (a corner) or across one direction (an edge).
    sharp_radius = 0.008
    tip = sq.superquadric_mesh(sq.Superquadric(0.005, 0.005, 0.005, 1.0, 1.0), EDGE / 4, TURN)
    assert np.all(sq.vertex_kinds(tip, sharp_radius) == sq.CORNER)
    rod = sq.superquadric_mesh(sq.Superquadric(0.005, 0.005, 0.04, 0.1, 1.0), EDGE / 4, TURN)
    kinds = sq.vertex_kinds(rod, sharp_radius)
    side = np.abs(np.asarray(rod.vertices)[:, 2]) < 0.03  # the cylinder's mantle, away from its end rims
    assert np.mean(kinds[side] == sq.EDGE) > 0.95
    big = sq.superquadric_mesh(sq.Superquadric(0.015, 0.015, 0.015, 1.0, 1.0), EDGE, TURN)
    assert np.all(sq.vertex_kinds(big, sharp_radius) == sq.SURFACE)  # the old 15 mm floor: no tips


def test_a_superellipse_far_larger_than_the_edge_budget_gets_the_capped_number_of_points():
    for closed in (True, False):
        with pytest.warns(UserWarning, match=f"needs \\d+ points .* meshed with {sq._MAX_CURVE_SAMPLES}, coarser"):
            u, v = sq.superellipse_samples(0.2, 1.0, 1.0, closed, 0.001, 0.05)
        assert len(u) == sq._MAX_CURVE_SAMPLES + (0 if closed else 1)
        np.testing.assert_allclose(np.abs(u) ** 10 + np.abs(v) ** 10, 1.0, atol=1e-9)  # still on the curve


@pytest.mark.slow
def test_a_shape_far_larger_than_the_edge_budget_meshes_coarser_not_out_of_memory():
    # A 2 m box at 1 mm edges would need ~8000 points per superellipse, 64M vertices: capped instead.
    huge = sq.Superquadric(1.0, 1.0, 1.0, 0.2, 0.2)
    with pytest.warns(UserWarning, match="coarser"):
        mesh = sq.superquadric_mesh(huge, 0.001, 0.05)
    n_rings, n_around = sq.grid_shape(mesh)
    assert n_around == sq._MAX_CURVE_SAMPLES and n_rings == sq._MAX_CURVE_SAMPLES - 1
    assert mesh.is_watertight and mesh.is_winding_consistent
    np.testing.assert_allclose(sq.radial_distance(huge, mesh.vertices), 1.0, atol=1e-9)


def test_sampled_contacts_lie_on_the_surface_with_outward_normals(meshes):
    rng = np.random.default_rng(2)
    for s, mesh in zip(SHAPES, meshes):
        p, n, _ = sq.sample_surface_contacts(s, mesh, 200, rng, 0.3, 0.15, 0.008)
        np.testing.assert_allclose(sq.radial_distance(s, p), 1.0, atol=1e-12)
        np.testing.assert_allclose(n, sq.surface_normals(s, p), atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
        assert np.all(np.sum(n * p, axis=1) > 0)


def training_cfg(**over):
    cfg = OmegaConf.load(CONF)
    cfg.mesh_max_edge, cfg.mesh_max_turn = EDGE, TURN
    for k, v in over.items():
        cfg[k] = v
    return cfg


def test_training_contacts_face_and_press_the_surface():
    contacts = sq.sample_training_contacts(60, np.random.default_rng(3), training_cfg(n_shapes=4))
    assert len(contacts) == 60
    shapes = [c.shape for c in contacts]
    # grouped by shape, 15 each, in order
    assert [shapes[i] for i in (0, 15, 30, 45)] == list(dict.fromkeys(shapes))
    assert all(shapes[i] == shapes[15 * (i // 15)] for i in range(60))
    assert sq.training_contact_groups(contacts) == [(0, 15), (15, 30), (30, 45), (45, 60)]
    cfg = training_cfg()
    for c in contacts:
        s, T = c.shape, c.T_object_sensor
        assert T.shape == (4, 4)
        assert cfg.depth_range[0] <= c.depth <= cfg.depth_range[1] and -np.pi <= c.roll < np.pi
        n = sensor.contact_normals(T)
        p = sensor.contact_points(T) - (0.002 - c.depth) * n  # the touched surface point
        assert sq.radial_distance(s, p[None])[0] == pytest.approx(1.0, abs=1e-9)
        np.testing.assert_allclose(sq.surface_normals(s, p[None])[0], n, atol=1e-9)
        apex = T[:3, :3] @ sensor.GEL_CENTER + T[:3, 3]
        assert sq.radial_distance(s, apex[None])[0] < 1.0  # the gel presses into the shape
        assert min(s.a, s.b, s.c) >= cfg.size_range[0] and max(s.e1, s.e2) <= cfg.exponent_range[1]


def test_training_contacts_are_reproducible_and_validated():
    a = sq.sample_training_contacts(10, np.random.default_rng(4), training_cfg(n_shapes=2))
    b = sq.sample_training_contacts(10, np.random.default_rng(4), training_cfg(n_shapes=2))
    assert all(x.shape == y.shape and np.array_equal(x.T_object_sensor, y.T_object_sensor) for x, y in zip(a, b))
    with pytest.raises(ConfigError):
        sq.sample_training_contacts(3, np.random.default_rng(0), training_cfg(n_shapes=5))
    bad = OmegaConf.create({"n_shapes": 1})
    with pytest.raises(ConfigError, match="lacks keys"):
        sq.sample_training_contacts(3, np.random.default_rng(0), bad)
