import numpy as np
import pytest
import trimesh

from tactile6d.core import geometry as g
from tactile6d.core.sensor import contact_normals, contact_points, sensor_poses_touching
from tactile6d.estimation import refine
from tactile6d.sim.surface_sampling import sample_surface


def _cut_box():
    """A 10 x 6 x 16 cm box with one corner cut off by a slanted plane."""
    box = trimesh.creation.box(extents=(0.10, 0.06, 0.16))
    cut = box.slice_plane([0.03, 0.0, 0.06], -g.rotvec_to_rotmat(np.array([0.0, 0.5, 0.0])) @ [0.0, 0.0, 1.0], cap=True)
    return cut


SURFACES = {}


def _surface(name):
    if name not in SURFACES:
        mesh = trimesh.creation.box(extents=(0.10, 0.06, 0.16)) if name == "box" else _cut_box()
        SURFACES[name] = sample_surface(mesh)
    return SURFACES[name]


# Contacts well inside faces: +x face, -y face, +z face (box); the cut face replaces +z on the cut box.
CONTACTS = {
    "box": (np.array([[0.05, 0.01, -0.02], [0.0, -0.03, 0.03], [-0.02, 0.0, 0.08]]),
            np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])),
}


def _cut_contacts(surface):
    """Three contacts on the cut box: the cut face, the -x face and the -y face."""
    normals = surface.normals
    cut = np.flatnonzero((normals[:, 0] > 0.2) & (normals[:, 2] > 0.2))
    cut_point = surface.points[cut].mean(axis=0)
    return (np.array([cut_point, [-0.05, 0.01, 0.0], [0.0, -0.03, -0.03]]),
            np.array([normals[cut[0]], [-1.0, 0, 0], [0, -1.0, 0]]))


@pytest.mark.parametrize("name", ["box", "cut_box"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_refinement_recovers_a_slightly_wrong_pose(name, seed):
    rng = np.random.default_rng(seed)
    surface = _surface(name)
    points, normals = CONTACTS["box"] if name == "box" else _cut_contacts(surface)
    T_true = g.make_pose(g.random_rotations(1, rng)[0], [0.1, 0.0, 0.2])
    T_sensors = T_true @ sensor_poses_touching(points, normals, rng.uniform(-np.pi, np.pi, 3), 0.002)
    s, n = contact_points(T_sensors), contact_normals(T_sensors)
    # Perturb by 2-5 mm and 2-5 deg.
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    wrong = T_true @ g.make_pose(g.rotvec_to_rotmat(axis / np.linalg.norm(axis) * np.radians(rng.uniform(2, 5))),
                                 direction / np.linalg.norm(direction) * rng.uniform(0.002, 0.005))
    refined = refine.refine_poses(refine.SurfaceFit(surface, s, n, normal_weight=0.01), wrong[None], n_iterations=10)[0]
    assert np.linalg.norm(refined[:3, 3] - T_true[:3, 3]) < 5e-4
    assert np.degrees(g.rotation_angle(refined[:3, :3], T_true[:3, :3])) < 0.5
    d, a = refine.surface_losses(refine.SurfaceFit(surface, s, n), refined[None])
    assert d[0] < 2e-4 and np.degrees(a[0]) < 0.5
    _d0, a0 = refine.surface_losses(refine.SurfaceFit(surface, s, n), wrong[None])
    assert a0[0] > a[0]


def test_refinement_is_vectorised_over_poses_and_keeps_a_right_pose():
    rng = np.random.default_rng(5)
    surface = _surface("box")
    points, normals = CONTACTS["box"]
    T_true = g.make_pose(g.random_rotations(1, rng)[0], [0.0, 0.1, 0.3])
    T_sensors = T_true @ sensor_poses_touching(points, normals, 0.0, 0.002)
    s, n = contact_points(T_sensors), contact_normals(T_sensors)
    starts = np.stack([T_true] + [T_true @ g.make_pose(g.rotvec_to_rotmat(rng.normal(scale=0.04, size=3)),
                                                        rng.normal(scale=0.002, size=3)) for _ in range(6)])
    out = refine.refine_poses(refine.SurfaceFit(surface, s, n), starts, n_iterations=10)
    assert out.shape == starts.shape
    np.testing.assert_allclose(out[:, :3, 3], np.repeat(T_true[None, :3, 3], 7, axis=0), atol=5e-4)
    assert np.linalg.norm(out[0, :3, 3] - T_true[:3, 3]) < 1e-6
    assert refine.refine_poses(refine.SurfaceFit(surface, s, n), np.zeros((0, 4, 4))).shape == (0, 4, 4)


def _face_patch(centre, normal, half_width=0.008, n=5):
    """An n x n grid of points on the face through ``centre`` with outward ``normal`` (a patch's pressed gel)."""
    normal = np.asarray(normal, dtype=float)
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    grid = np.linspace(-half_width, half_width, n)
    return np.array([centre + u * a + v * b for u in grid for v in grid])


def test_patch_points_fix_the_rotation_that_three_contact_points_leave_free():
    rng = np.random.default_rng(7)
    surface = _surface("box")
    points, normals = CONTACTS["box"]
    T_true = g.make_pose(g.random_rotations(1, rng)[0], [0.1, 0.0, 0.2])
    s = points @ T_true[:3, :3].T + T_true[:3, 3]
    n = normals @ T_true[:3, :3].T
    patch = np.concatenate([_face_patch(p, m) for p, m in zip(points, normals)]) @ T_true[:3, :3].T + T_true[:3, 3]
    weights = np.full(len(patch), 1.0 / np.sqrt(25))
    wrong = T_true @ g.make_pose(g.rotvec_to_rotmat(np.radians(4.0) * np.array([0.6, 0.0, 0.8])), [0.002, -0.002, 0.001])
    # Three point-to-plane residuals (no normal term) leave three degrees of freedom to the prior.
    points_only = refine.refine_poses(refine.SurfaceFit(surface, s, n, normal_weight=0.0), wrong[None], n_iterations=10)[0]
    assert np.degrees(g.rotation_angle(points_only[:3, :3], T_true[:3, :3])) > 1.0
    with_patch = refine.refine_poses(refine.SurfaceFit(surface, s, n, normal_weight=0.0), wrong[None], n_iterations=10,
                                     patch_points=patch, patch_weights=weights)[0]
    assert np.degrees(g.rotation_angle(with_patch[:3, :3], T_true[:3, :3])) < 0.3
    assert np.linalg.norm(with_patch[:3, 3] - T_true[:3, 3]) < 5e-4


def test_sensor_corrections_vanish_as_their_sigmas_do():
    # With the sensor poses declared (nearly) exact, the joint fit is the plain refinement.
    rng = np.random.default_rng(3)
    surface = _surface("box")
    points, normals = CONTACTS["box"]
    T_true = g.make_pose(g.random_rotations(1, rng)[0], [0.1, 0.0, 0.2])
    T_sensors = T_true @ sensor_poses_touching(points, normals, 0.0, 0.002)
    s, n = contact_points(T_sensors), contact_normals(T_sensors)
    wrong = T_true @ g.make_pose(g.rotvec_to_rotmat(np.radians(3.0) * np.array([0.0, 0.6, 0.8])), [0.002, 0.001, -0.002])
    plain = refine.refine_poses(refine.SurfaceFit(surface, s, n), wrong[None], n_iterations=10)
    joint, seen = refine.refine_poses_and_sensors(refine.SurfaceFit(surface, s, n), wrong[None], 1e-9, 1e-9, n_iterations=10)
    assert seen.shape == (1, 3, 4, 4)
    np.testing.assert_allclose(joint, plain, atol=1e-6)
    np.testing.assert_allclose(seen, np.repeat(joint[:, None], 3, axis=1), atol=1e-6)


def test_sensor_corrections_absorb_what_no_object_pose_explains():
    # Two sensors squeeze the box's +-x faces, a third touches +z, each with its patch's points; the +x
    # sensor reports its contact 2 mm outside the face (its pose is off). No object pose touches all three:
    # the plain refinement turns the object by degrees to spread the contradiction, the joint fit shares the
    # 2 mm between the two squeezing sensors (equal priors) and keeps the object's orientation.
    surface = _surface("box")
    T_true = g.make_pose(g.rotvec_to_rotmat(np.array([0.3, -0.2, 0.5])), [0.1, 0.0, 0.2])
    local_points = np.array([[0.052, 0.01, -0.02], [-0.05, -0.01, 0.02], [0.01, 0.0, 0.08]])
    local_normals = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0]])
    local_patch = np.concatenate([_face_patch(p, m) for p, m in zip(local_points, local_normals)])
    s, n = local_points @ T_true[:3, :3].T + T_true[:3, 3], local_normals @ T_true[:3, :3].T
    patch, owners, weights = local_patch @ T_true[:3, :3].T + T_true[:3, 3], np.repeat(np.arange(3), 25), np.full(75, 0.2)
    sigma_contact, sigma_angle = 0.0015, np.radians(1.5)
    fit = refine.SurfaceFit(surface, s, n)
    plain = refine.refine_poses(fit, T_true[None], n_iterations=10, patch_points=patch, patch_weights=weights)
    joint, seen = refine.refine_poses_and_sensors(fit, T_true[None], sigma_contact, sigma_angle, n_iterations=10,
                                                  patch_points=patch, patch_weights=weights, patch_owners=owners)
    assert np.degrees(g.rotation_angle(plain[0, :3, :3], T_true[:3, :3])) > 1.5
    assert np.degrees(g.rotation_angle(joint[0, :3, :3], T_true[:3, :3])) < 1.0
    _, angle_plain = refine.surface_losses(fit, plain)
    _, angle_joint = refine.surface_losses(fit, seen)
    assert angle_joint[0] < 0.5 * angle_plain[0]
    # Each squeezing sensor sees the object moved along x (object frame), one each way; the third hardly at all.
    shifts = np.array([(np.linalg.inv(joint[0]) @ seen[0, i])[:3, 3] for i in range(3)])
    assert shifts[0, 0] > 5e-4 and shifts[1, 0] < -5e-4
    assert np.linalg.norm(shifts[2]) < 4e-4
    # The cost: 0 without corrections, and the squared Mahalanobis norm, so a quarter with sigmas twice as large.
    cost = refine.sensor_corrections_cost(joint, seen, s, sigma_contact, sigma_angle)
    assert cost[0] > 0.05
    np.testing.assert_allclose(refine.sensor_corrections_cost(joint, seen, s, 2 * sigma_contact, 2 * sigma_angle),
                               cost / 4, rtol=1e-9)
    np.testing.assert_allclose(refine.sensor_corrections_cost(joint, np.repeat(joint[:, None], 3, axis=1), s,
                                                              sigma_contact, sigma_angle), 0.0, atol=1e-12)


def _free_rows_naive(q, surface, margin):
    """``refine.free_rows`` one point at a time, the nearest sample found by brute force."""
    r, J, active = np.zeros(q.shape[:2]), np.zeros(q.shape[:2] + (6,)), np.zeros(q.shape[:2], bool)
    for p in range(q.shape[0]):
        for f in range(q.shape[1]):
            k = int(np.argmin(np.linalg.norm(surface.points - q[p, f], axis=1)))
            c, m = surface.points[k], surface.normals[k]
            signed = float(m @ (q[p, f] - c)) + margin
            J[p, f] = np.concatenate([-m, np.cross(m, q[p, f])])
            if signed < 0 and np.linalg.norm(q[p, f] - c) < 2.5 * refine._ROBUST_DISTANCE:
                r[p, f], active[p, f] = signed, True
    return r, J, active


def test_free_rows_push_only_points_inside_the_surface_as_a_naive_loop_does():
    rng = np.random.default_rng(5)
    surface = _surface("box")
    # Points within a few millimetres of the +x and +z faces, inside and out, and some far off the surface.
    near = np.concatenate([[0.05, 0.0, 0.0] + rng.uniform([-0.004, -0.02, -0.05], [0.004, 0.02, 0.05], (20, 3)),
                           [0.0, 0.0, 0.08] + rng.uniform([-0.03, -0.02, -0.004], [0.03, 0.02, 0.004], (20, 3)),
                           rng.uniform(-0.2, 0.2, (8, 3)) + [0.3, 0.0, 0.0]])
    q = np.stack([near, near + 0.001])
    r, J, active = refine.free_rows(q, surface, 3e-4)
    r_naive, J_naive, active_naive = _free_rows_naive(q, surface, 3e-4)
    np.testing.assert_array_equal(active, active_naive)
    np.testing.assert_allclose(r, r_naive, atol=1e-12)
    np.testing.assert_allclose(J, J_naive, atol=1e-12)
    assert active[0].sum() > 5 and (r[active] < 0).all() and (r[~active] == 0).all()
    assert not active[:, -8:].any()  # far from the surface: no opinion


def _ring_above_face(centre, normal, height, radii=(0.010, 0.014), n=12):
    """Points on rings around ``centre`` on a face with outward ``normal``, ``height`` m outside it: the
    gel around a patch, which a pose tilted towards it would press."""
    normal = np.asarray(normal, dtype=float)
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.array([centre + height * normal + rad * (np.cos(t) * a + np.sin(t) * b) for rad in radii for t in angles])


def test_untouched_gel_rows_fix_the_turn_three_contact_points_leave_free_and_leave_the_truth_alone():
    rng = np.random.default_rng(7)
    surface = _surface("box")
    points, normals = CONTACTS["box"]
    T_true = g.make_pose(g.random_rotations(1, rng)[0], [0.1, 0.0, 0.2])
    s, n = points @ T_true[:3, :3].T + T_true[:3, 3], normals @ T_true[:3, :3].T
    free = np.concatenate([_ring_above_face(p, m, 5e-5) for p, m in zip(points, normals)]) @ T_true[:3, :3].T + T_true[:3, 3]
    weights = np.full(len(free), 3.0 / np.sqrt(24))
    fit = refine.SurfaceFit(surface, s, n, normal_weight=0.0)
    wrong = T_true @ g.make_pose(g.rotvec_to_rotmat(np.radians(4.0) * np.array([0.6, 0.0, 0.8])), [0.002, -0.002, 0.001])
    points_only = refine.refine_poses(fit, wrong[None], n_iterations=10)[0]
    with_free = refine.refine_poses(fit, wrong[None], n_iterations=10, free_points=free, free_weights=weights)[0]
    assert np.degrees(g.rotation_angle(points_only[:3, :3], T_true[:3, :3])) > 1.0
    assert np.degrees(g.rotation_angle(with_free[:3, :3], T_true[:3, :3])) < 0.5
    # No free point lies inside the refined pose's surface by more than a fraction of a millimetre.
    r, _, _ = refine.free_rows(np.einsum("ba,mb->ma", with_free[:3, :3], free - with_free[:3, 3])[None], surface, 0.0)
    assert r.min() > -2e-4
    # At the truth nothing is violated: the rows are one-sided, so the true pose stays put.
    kept = refine.refine_poses(fit, T_true[None], n_iterations=10, free_points=free, free_weights=weights)[0]
    np.testing.assert_allclose(kept, T_true, atol=1e-9)


def test_untouched_gel_rows_move_the_sensor_that_presses_its_free_gel():
    # The box squeezed on its +-x faces and touched on +z, each sensor's patch fitted; sensor 0 also reports
    # its untouched gel 0.5 mm inside the +x face (its pose is off towards the object): with the sensors'
    # corrections on, the free rows move what sensor 0 sees out of its free gel.
    surface = _surface("box")
    T_true = g.make_pose(g.rotvec_to_rotmat(np.array([0.3, -0.2, 0.5])), [0.1, 0.0, 0.2])
    local_points = np.array([[0.05, 0.01, -0.02], [-0.05, -0.01, 0.02], [0.01, 0.0, 0.08]])
    local_normals = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0]])
    local_patch = np.concatenate([_face_patch(p, m) for p, m in zip(local_points, local_normals)])
    to_world = (lambda x: x @ T_true[:3, :3].T + T_true[:3, 3])
    s, n = to_world(local_points), local_normals @ T_true[:3, :3].T
    patch, owners, weights = to_world(local_patch), np.repeat(np.arange(3), 25), np.full(75, 0.2)
    free = to_world(_ring_above_face(local_points[0], local_normals[0], -5e-4))
    fit = refine.SurfaceFit(surface, s, n)
    args = dict(n_iterations=10, patch_points=patch, patch_weights=weights, patch_owners=owners)
    _, seen_plain = refine.refine_poses_and_sensors(fit, T_true[None], 0.0015, np.radians(1.5), **args)
    joint, seen = refine.refine_poses_and_sensors(fit, T_true[None], 0.0015, np.radians(1.5), **args,
                                                  free_points=free, free_weights=np.full(len(free), 3.0 / np.sqrt(24)),
                                                  free_owners=np.zeros(len(free), dtype=int))
    np.testing.assert_allclose(seen_plain[0, 0], T_true, atol=1e-6)  # without the rows nothing to correct
    inside = (lambda T: -refine.free_rows(np.einsum("ba,mb->ma", T[:3, :3], free - T[:3, 3])[None], surface, 0.0)[0].min())
    assert inside(seen_plain[0, 0]) > 4e-4 and inside(seen[0, 0]) < 2e-4
    shifts = np.array([(np.linalg.inv(joint[0]) @ seen[0, i])[:3, 3] for i in range(3)])
    # Sensor 0 sees the object moved away from its gel (-x in the object frame); its pressed points, which the
    # free gel 0.5 mm inside the face contradicts, hold part of it back, and the squeezing sensor 1 shares it.
    assert shifts[0, 0] < -1e-4
