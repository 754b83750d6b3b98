
import numpy as np
import pytest
import trimesh

from tactile6d.core import geometry as g
from tactile6d.core import sensor
from tactile6d.evaluation import contact_accuracy
from tactile6d.sim import contact_types as C
from tactile6d.sim import surface_sampling

BOX_EXTENTS = np.array([0.06, 0.08, 0.10])
HX, HY, HZ = BOX_EXTENTS / 2


@pytest.fixture(scope="module")
def box():
    return surface_sampling.sample_surface(trimesh.creation.box(BOX_EXTENTS))


def _names(surface, points, normals):
    return list(C.contact_type_names(C.classify_contacts(surface, points, normals)))


def _single(*args):
    """The accuracy of one estimate: ``(correct, details)``."""
    return contact_accuracy.accuracy_to_details(contact_accuracy.contact_accuracy(*args))


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_box_faces_edges_corners(box):
    points = np.array([[0, 0, HZ], [HX, 0.01, -0.02], [HX, HY, 0], [0, -HY, HZ], [HX, HY, HZ], [-HX, -HY, -HZ]])
    normals = _unit([[0, 0, 1], [1, 0, 0], [1, 1, 0], [0, -1, 1], [1, 1, 1], [-1, -1, -1]])
    assert _names(box, points, normals) == ["flat", "flat", "edge", "edge", "corner", "corner"]
    # a sensor pressing a face flat, right at its edge, touches the edge too
    assert _names(box, [[HX, HY, 0]], [[1, 0, 0]]) == ["edge"]


def test_cylinder_and_sphere():
    cyl = surface_sampling.sample_surface(trimesh.creation.cylinder(radius=0.03, height=0.1, sections=128))
    points = [[0.03, 0, 0], [0, -0.03, 0.02], [0, 0, 0.05], [0.01, 0.0, -0.05], [0.03, 0, 0.05], [0, -0.03, -0.05]]
    normals = _unit([[1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [1, 0, 1], [0, -1, -1]])
    assert _names(cyl, points, normals) == ["curved", "curved", "flat", "flat", "edge", "edge"]
    sphere = surface_sampling.sample_surface(trimesh.creation.icosphere(subdivisions=4, radius=0.04))
    dirs = _unit(np.random.default_rng(0).normal(size=(6, 3)))
    assert _names(sphere, 0.04 * dirs, dirs) == ["curved"] * 6


def test_thin_cylinder_side_is_curved_not_edge():
    # a marker-sized cylinder (radius 1 cm) bends smoothly: no facets, no sharp crease
    thin = surface_sampling.sample_surface(trimesh.creation.cylinder(radius=0.01, height=0.12, sections=128))
    assert _names(thin, [[0.01, 0, 0], [0, 0.01, 0.03]], [[1, 0, 0], [0, 1, 0]]) == ["curved", "curved"]


def test_winding_sign_of_signed_distance():
    mesh = trimesh.creation.box(BOX_EXTENTS)
    d, nearest = C.signed_distances(mesh, [[0, 0, HZ + 0.002], [0, 0, HZ - 0.001], [HX + 0.003, HY + 0.004, 0]])
    np.testing.assert_allclose(d, [0.002, -0.001, 0.005], atol=1e-9)
    np.testing.assert_allclose(nearest[2], [HX, HY, 0], atol=1e-9)


def _scene(rng):
    """A box at a random pose touched by three sensors on a face, an edge and a corner."""
    T_gt = g.make_pose(g.random_rotations(1, rng)[0], [0.1, 0.0, 0.2])
    points = np.array([[HX, 0.005, -0.01], [0, HY, HZ], [-HX, -HY, HZ]])
    normals = _unit([[1, 0, 0], [0, 1, 1], [-1, -1, 1]])
    T_sensors = T_gt @ sensor.sensor_poses_touching(points, normals, rolls=rng.uniform(-np.pi, np.pi, 3))
    return T_gt, T_sensors


def _winding_numbers_reference(mesh, points):
    """Van Oosterom & Strackee over every (point, triangle) pair at once, through np.cross and np.linalg.norm."""
    rel = np.asarray(mesh.triangles)[None] - np.asarray(points, dtype=np.float64)[:, None, None, :]
    a, b, c = rel[..., 0, :], rel[..., 1, :], rel[..., 2, :]
    la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
    det = np.sum(a * np.cross(b, c), axis=-1)
    den = la * lb * lc + np.sum(a * b, -1) * lc + np.sum(b * c, -1) * la + np.sum(c * a, -1) * lb
    return np.sum(np.arctan2(det, den), axis=-1) / (2.0 * np.pi)


def test_winding_numbers_are_the_reference_bits_and_one_inside_zero_outside():
    rng = np.random.default_rng(3)
    for mesh in (trimesh.creation.icosphere(subdivisions=3, radius=0.04),
                 trimesh.creation.box(extents=(0.1, 0.06, 0.16)),
                 trimesh.creation.cylinder(radius=0.03, height=0.1, sections=40)):
        points = np.concatenate([rng.uniform(-0.09, 0.09, (40, 3)), mesh.vertices[:10] * 1.001])
        fast = C.winding_numbers(mesh, points)
        np.testing.assert_array_equal(fast, _winding_numbers_reference(mesh, points))
        inside = mesh.contains(points[:40])
        np.testing.assert_allclose(fast[:40], inside.astype(float), atol=1e-9)


def test_contact_accuracy_at_the_true_pose(box):
    T_gt, T_sensors = _scene(np.random.default_rng(5))
    ok, details = _single(box, T_gt, T_gt, T_sensors)
    assert ok
    assert list(details["type_true_names"]) == ["flat", "edge", "corner"]
    np.testing.assert_allclose(details["signed_distance"], 0.0002, atol=1e-6)
    assert details["facing"].all()


def test_contact_accuracy_rejects_a_gap(box):
    T_gt, T_sensors = _scene(np.random.default_rng(6))
    # move the object 1 cm away from the face sensor, along that face's normal (+x of the object)
    T_est = T_gt @ g.make_pose(np.eye(3), [-0.01, 0, 0])
    ok, details = _single(box, T_est, T_gt, T_sensors)
    assert not ok
    assert details["signed_distance"][0] == pytest.approx(0.0102, abs=1e-6)
    assert not details["touching"][0]


def test_contact_accuracy_rejects_a_changed_contact_type(box):
    rng = np.random.default_rng(7)
    T_gt = g.make_pose(g.random_rotations(1, rng)[0], [0.1, 0.0, 0.2])
    # three face contacts on faces parallel to x; the first 12 mm from the +x edge of the top face
    points = np.array([[HX - 0.012, 0, HZ], [0, -HY, 0], [0.0, 0.01, -HZ]])
    normals = np.array([[0, 0, 1.0], [0, -1, 0], [0, 0, -1]])
    T_sensors = T_gt @ sensor.sensor_poses_touching(points, normals)
    assert _single(box, T_gt, T_gt, T_sensors)[0]
    # slide the object 12 mm along -x: every sensor still touches, but the first now sits on an edge
    T_est = T_gt @ g.make_pose(np.eye(3), [-0.012, 0, 0])
    ok, details = _single(box, T_est, T_gt, T_sensors)
    assert not ok
    assert details["touching"].all()
    assert list(details["type_est_names"]) == ["edge", "flat", "flat"]
    assert list(details["same_type"]) == [False, True, True]


def test_contact_accuracy_rejects_a_sensor_side_on(box):
    # the contact point lies on the top face, but the sensor looks sideways (along -x): its gel
    # cannot press a surface whose normal is perpendicular to its axis
    T_sensor = sensor.sensor_poses_touching(np.array([0, 0, HZ]), np.array([1.0, 0, 0]), depths=0.002)
    ok, details = _single(box, np.eye(4), np.eye(4), T_sensor[None])
    assert not ok
    assert abs(details["signed_distance"][0]) < 1e-9 and not details["facing"][0]


def test_batched_matches_single(box):
    rng = np.random.default_rng(8)
    T_gt, T_sensors = _scene(rng)
    T_est = np.stack([T_gt, T_gt @ g.make_pose(np.eye(3), [0.02, 0, 0]), T_gt @ g.make_pose(np.eye(3), [0, 0, 0.001])])
    result = contact_accuracy.contact_accuracy(box, T_est, T_gt, T_sensors)
    assert result["correct"].shape == (3,) and result["signed_distance"].shape == (3, 3)
    assert list(result["correct"]) == [_single(box, T, T_gt, T_sensors)[0] for T in T_est]
    assert result["correct"][0] and not result["correct"][1]


@pytest.fixture(scope="module")
def sugar_box(data_dir):
    data = data_dir
    mesh = trimesh.load(data / "ycb" / "004_sugar_box" / "textured_simple.obj", force="mesh", process=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return data, surface_sampling.sample_surface(mesh)


def test_sugar_box_face_and_edge(sugar_box):
    _, surface = sugar_box
    lo, hi = surface.mesh.bounds
    mid = (lo + hi) / 2
    # the middle of the large +-y faces (0.05 x 0.176 m) and the middle of a long edge (along z)
    points = [[mid[0], hi[1], mid[2]], [mid[0], lo[1], mid[2] + 0.02], [hi[0], hi[1], mid[2]], [lo[0], lo[1], mid[2]]]
    normals = _unit([[0, 1, 0], [0, -1, 0], [1, 1, 0], [-1, -1, 0]])
    assert _names(surface, points, normals) == ["flat", "flat", "edge", "edge"]


def test_sugar_box_paper_triplets_are_correct_at_the_true_pose(sugar_box):
    data, surface = sugar_box
    T_gt = g.make_pose(np.eye(3), [0.1, 0.0, 0.2])
    for k in range(1, 5):
        text = (data / "caddeo2023" / "triplets" / "004_sugar_box" / f"triplet_{k}" / "poses_sensors.txt").read_text()
        ok, details = _single(surface, T_gt, T_gt, g.text_to_poses(text))
        assert ok, details


def test_a_sensor_facing_away_from_every_surface_gets_no_type():
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    # on the +z face, but approaching from inside the box: no surface faces it
    codes = C.classify_contacts(box, np.array([[0.0, 0.0, 0.02]]), np.array([[0.0, 0.0, -1.0]]))
    assert codes.tolist() == [C.NO_SURFACE]
    assert C.contact_type_names(codes).tolist() == ["none"]


def test_sharpness_ranks_order_flat_edge_corner_and_leave_the_rest_out():
    codes = np.array([C.FLAT, C.EDGE, C.CORNER, C.CURVED, C.NO_SURFACE])
    assert C.sharpness_ranks(codes).tolist() == [0, 1, 2, -1, -1]
    assert C.sharpness_ranks(codes.astype(np.int8).reshape(1, 5)).shape == (1, 5)
