import io
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tactile6d.core import geometry as g
from tactile6d.core.errors import InputError
from tactile6d.estimation import optimize as opt

HALF = np.array([0.05, 0.03, 0.08])  # a 10 x 6 x 16 cm box, the size of a YCB object


def _scene(rng, n_sensors, noise=0.0):
    """Points on the box (object frame), a random true pose, the sensor points it puts in the world."""
    p = rng.uniform(-HALF, HALF, (n_sensors, 3))
    axis = rng.integers(0, 3, n_sensors)
    p[np.arange(n_sensors), axis] = np.where(rng.random(n_sensors) < 0.5, -1, 1) * HALF[axis]
    T = g.make_pose(g.random_rotations(1, rng)[0], rng.uniform(-0.3, 0.3, 3))
    return p + rng.normal(scale=noise, size=p.shape), g.transform_points(T, p), T


def _errors(pose, T):
    return np.linalg.norm(pose[:3, 3] - T[:3, 3]), np.degrees(g.rotation_angle(pose[:3, :3], T[:3, :3]))


def test_initial_translations_are_the_centroid_faces_and_corners():
    s = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0.3]])
    t = opt.initial_translations(s, 0.2)
    assert t.shape == (15, 3)
    np.testing.assert_allclose(t[0], s.mean(0))
    d = np.linalg.norm(t - s.mean(0), axis=1)
    np.testing.assert_allclose(d[1:7], 0.2)
    np.testing.assert_allclose(d[7:], 0.2 * np.sqrt(3))
    assert len({tuple(np.round(v, 9)) for v in t}) == 15


def test_loss_matches_a_per_pose_loop():
    rng = np.random.default_rng(0)
    poses = g.make_pose(g.random_rotations(5, rng), rng.normal(size=(5, 3)))
    p, s = rng.normal(size=(5, 3, 3)), rng.normal(size=(3, 3))
    naive = [np.mean([np.linalg.norm(s[i] - (T[:3, :3] @ q[i] + T[:3, 3])) for i in range(3)]) for T, q in zip(poses, p)]
    np.testing.assert_allclose(opt.poses_to_losses(poses, p, s), naive, rtol=1e-12)


@pytest.mark.parametrize("n_sensors", [3, 4, 6])
def test_fast_solver_recovers_a_random_pose_from_exact_correspondences(n_sensors):
    rng = np.random.default_rng(n_sensors)
    for _ in range(10):
        p, s, T = _scene(rng, n_sensors)
        fit = opt.fit_fast(p[None], s, g.random_rotations(1, rng), n_irls=5)
        dt, dr = _errors(fit.poses[0], T)
        assert dt < 1e-3 and dr < 0.1
        assert fit.losses[0] < 1e-9


def test_weighted_kabsch_matches_brute_force_weighted_least_squares():
    rng = np.random.default_rng(1)
    p, s, _ = _scene(rng, 5, noise=0.003)
    w = rng.uniform(0.1, 2.0, (1, 5))
    T = opt.weighted_kabsch(p[None], s, w)[0]

    def cost(pose):
        return np.sum(w[0] * np.sum((s - g.transform_points(pose, p)) ** 2, axis=1))

    # No small perturbation of the closed-form answer does better.
    for _ in range(200):
        dT = g.se3_exp(rng.normal(scale=1e-3, size=6))
        assert cost(T @ dT) >= cost(T) - 1e-15


def test_irls_lowers_the_plain_distance_loss_to_a_local_minimum():
    rng = np.random.default_rng(2)
    for _ in range(5):
        p, s, _ = _scene(rng, 3, noise=0.003)
        kabsch = opt.fit_fast(p[None], s, np.eye(3)[None], n_irls=0)
        irls = opt.fit_fast(p[None], s, np.eye(3)[None], n_irls=50)
        assert irls.losses[0] <= kabsch.losses[0] + 1e-12
        around = g.se3_exp(rng.normal(scale=2e-4, size=(300, 6))) @ irls.poses[0]
        losses = opt.poses_to_losses(around, np.repeat(p[None], 300, 0), s)
        assert losses.min() >= irls.losses[0] - 2e-7  # within what 50 steps of IRLS leave


def test_two_sensors_reach_the_lower_bound_nearest_the_random_rotation():
    rng = np.random.default_rng(3)
    p, s, _ = _scene(rng, 2, noise=0.003)
    R0 = g.random_rotations(50, rng)
    fit = opt.fit_fast(np.repeat(p[None], 50, 0), s, R0, n_irls=5)
    bound = abs(np.linalg.norm(s[1] - s[0]) - np.linalg.norm(p[1] - p[0])) / 2
    np.testing.assert_allclose(fit.losses, bound, atol=1e-12)
    # The correction is the angle between R0 (p2 - p1) and s2 - s1, no more.
    u = np.einsum("nab,b->na", R0, p[1] - p[0])
    v = s[1] - s[0]
    need = np.arccos(np.clip(u @ v / np.linalg.norm(u, axis=1) / np.linalg.norm(v), -1, 1))
    np.testing.assert_allclose(g.rotation_angle(R0, fit.poses[:, :3, :3]), need, atol=1e-9)
    # Different random rotations give different hypotheses (rotations about s2 - s1).
    assert np.ptp(g.rotation_angle(fit.poses[:1, :3, :3], fit.poses[:, :3, :3])) > 1.0


def test_one_sensor_keeps_the_random_rotation_and_touches_exactly():
    rng = np.random.default_rng(4)
    p, s, _ = _scene(rng, 1)
    R0 = g.random_rotations(4, rng)
    fit = opt.fit_fast(np.repeat(p[None], 4, 0), s, R0, n_irls=5)
    np.testing.assert_allclose(fit.poses[:, :3, :3], R0)
    np.testing.assert_allclose(fit.losses, 0, atol=1e-15)


@pytest.mark.slow
def test_gd_step_is_the_gradient_of_the_loss():
    # One step with unit gains returns xi - dE/dxi: compare with central differences in float64.
    rng = np.random.default_rng(5)
    p, s, T = _scene(rng, 3, noise=0.01)
    R0 = g.random_rotations(1, rng)
    t0 = T[:3, 3] + rng.normal(scale=0.02, size=3)
    xi0 = np.concatenate([t0, g.rotmat_to_rotvec(R0[0])])
    fit = opt.fit_gd(p[None], s, R0, t0[None], 1, 1.0, 1.0, precision="float64")
    grad = xi0 - g.pose_to_xi(fit.poses[0])

    def loss(xi):
        return opt.poses_to_losses(g.xi_to_pose(xi)[None], p[None], s)[0]

    h = 1e-6
    numeric = [(loss(xi0 + h * e) - loss(xi0 - h * e)) / (2 * h) for e in np.eye(6)]
    np.testing.assert_allclose(grad, numeric, atol=1e-7)


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.slow
def test_gd_program_holds_no_approximate_square_root(precision):
    """XLA rewrites x / sqrt(y) as x * rsqrt(y), and compiles rsqrt on the CPU from the approximate vrsqrtps
    and two Newton steps, whose last bit is the CPU vendor's: the paper's gradient descent, chaotic at its
    gains, then ended elsewhere on an Intel Xeon than on an AMD EPYC. Its optimised program (the gradient
    included) must take square roots only, which every x86-64 CPU rounds alike."""
    import jax
    import jax.numpy as jnp

    with jax.enable_x64(precision == "float64"):
        dtype = jnp.dtype(precision)
        program = opt._gd_program(3, 0.01, 1.0)
        text = program.lower(jnp.zeros((6, 16), dtype), jnp.zeros((3, 3, 16), dtype),
                             jnp.zeros((3, 3), dtype)).compile().as_text()
    assert " sqrt(" in text
    assert "rsqrt(" not in text


@pytest.mark.slow
def test_gd_steps_are_repeated_single_steps_with_each_gain_on_its_components():
    # Three steps at gains (0.3, 0.7) against a naive loop: xi <- xi - diag(0.3 I3, 0.7 I3) dE/dxi, the
    # gradient by central differences, in float64.
    rng = np.random.default_rng(15)
    p, s, T = _scene(rng, 3, noise=0.01)
    R0 = g.random_rotations(1, rng)
    t0 = T[:3, 3] + rng.normal(scale=0.02, size=3)

    def loss(xi):
        return opt.poses_to_losses(g.xi_to_pose(xi)[None], p[None], s)[0]

    xi = np.concatenate([t0, g.rotmat_to_rotvec(R0[0])])
    gains = np.array([0.3] * 3 + [0.7] * 3)
    for _ in range(3):
        xi = xi - gains * np.array([(loss(xi + 1e-6 * e) - loss(xi - 1e-6 * e)) / 2e-6 for e in np.eye(6)])
    fit = opt.fit_gd(p[None], s, R0, t0[None], 3, 0.3, 0.7, precision="float64")
    np.testing.assert_allclose(g.pose_to_xi(fit.poses[0]), xi, atol=1e-7)


def test_gd_batch_size_is_the_least_padded_size_of_few():
    # Naive reference: every size c * 2^k (16 <= c <= 31, and 1..15) that is a multiple, the least >= n.
    sizes = sorted({c * 2**k for k in range(14) for c in range(16, 32)} | set(range(1, 16)))
    for multiple in (1, 64, 128):
        for n in [1, 5, 16, 31, 33, 100, 255, 4080, 50685, 58860, 75000]:
            expected = min(x for x in sizes if x >= n and x % multiple == 0)
            assert opt.gd_batch_size(n, multiple) == expected, (n, multiple)
            assert opt.gd_batch_size(n, multiple) <= max(1.0625 * n, n + 2 * multiple)


@pytest.mark.slow
def test_gd_poses_do_not_depend_on_the_rest_of_the_batch(monkeypatch):
    # A tuple's poses are the same bits alone (padded to 64 poses), among 40 other tuples (615 poses, padded
    # to 640) and when those run in chunks (of 128 here), so neither the padding, nor the tuple count of an
    # estimate, nor the chunking moves them.
    rng = np.random.default_rng(16)
    p = rng.normal(scale=0.05, size=(41, 3, 3))
    s = p[0] + 0.1
    R0 = g.random_rotations(41, rng)
    t0 = opt.initial_translations(s, 0.2)
    alone = opt.fit_gd(p[:1], s, R0[:1], t0, 30, 0.01, 1.0)
    among = opt.fit_gd(p, s, R0, t0, 30, 0.01, 1.0)
    np.testing.assert_array_equal(among.poses[among.tuple_index == 0], alone.poses)
    monkeypatch.setattr(opt, "GD_CHUNK", 128)
    chunked = opt.fit_gd(p, s, R0, t0, 30, 0.01, 1.0)
    np.testing.assert_array_equal(chunked.poses, among.poses)
    np.testing.assert_array_equal(chunked.tuple_index, among.tuple_index)


@pytest.mark.slow
def test_gd_converges_with_small_gains_and_cycles_within_a_bound_with_the_papers():
    # With plain distances every residual's gradient has unit norm, so at the paper's gains
    # (0.01, 1) GD ends in a limit cycle millimetres wide; smaller gains converge tightly.
    rng = np.random.default_rng(6)
    for _ in range(3):
        p, s, T = _scene(rng, 3)
        R0 = (g.rotvec_to_rotmat(rng.normal(scale=0.03, size=3)) @ T[:3, :3])[None]
        t0 = (T[:3, 3] + rng.normal(scale=0.003, size=3))[None]
        fine = opt.fit_gd(p[None], s, R0, t0, 700, 1e-4, 1e-2)
        dt, dr = _errors(fine.poses[0], T)
        assert dt < 1e-3 and dr < 0.1
        paper = opt.fit_gd(p[None], s, R0, t0, 700, 0.01, 1.0)
        dt, dr = _errors(paper.poses[0], T)
        assert dt < 0.012 and dr < 3.0


@pytest.mark.slow
def test_gd_from_the_papers_starts_finds_the_pose_with_exact_correspondences():
    rng = np.random.default_rng(7)
    p, s, T = _scene(rng, 3)
    n = 20  # the same tuple with 20 random rotations, 15 translations each
    fit = opt.fit_gd(np.repeat(p[None], n, 0), s, g.random_rotations(n, rng), opt.initial_translations(s, 0.2), 700, 0.01, 1.0)
    assert fit.poses.shape == (15 * n, 4, 4)
    dt, dr = _errors(fit.poses[np.argmin(fit.losses)], T)
    assert dt < 0.012 and dr < 3.0


@pytest.mark.slow
def test_tuples_to_poses_shapes_and_tuple_index():
    rng = np.random.default_rng(8)
    points = rng.normal(scale=0.05, size=(30, 3))
    s = points[[1, 2, 3]] + 0.1
    tuples = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9], [1, 5, 9]])
    fast = opt.tuples_to_poses(points, s, tuples, "fast", rng)
    assert fast.poses.shape == (4, 4, 4) and fast.losses.shape == (4,)
    np.testing.assert_array_equal(fast.tuple_index, np.arange(4))
    assert fast.losses[0] < 1e-9
    gd = opt.tuples_to_poses(points, s, tuples, "gd", rng, n_steps=5)
    assert gd.poses.shape == (60, 4, 4) and gd.poses.dtype == np.float64
    np.testing.assert_array_equal(gd.tuple_index, np.tile(np.arange(4), 15))
    np.testing.assert_allclose(gd.losses, opt.poses_to_losses(gd.poses, points[tuples[gd.tuple_index]], s))
    with pytest.raises(InputError):
        opt.tuples_to_poses(points, s, tuples, "newton", rng)
    with pytest.raises(InputError):
        opt.tuples_to_poses(points, s, tuples[:, :2], "fast", rng)


@pytest.mark.slow
def test_gd_splits_over_two_cpu_devices_with_the_same_result():
    # A fresh interpreter, since JAX's device count is fixed once it has run anything.
    code = textwrap.dedent(
        """
        import io, sys
        import numpy as np
        from tactile6d.estimation import optimize as opt
        from tactile6d.core import geometry as g
        assert opt.use_cpu_devices(2) == 2
        rng = np.random.default_rng(0)
        p = rng.normal(scale=0.05, size=(7, 3, 3)); s = p[0] + 0.1
        R0 = g.random_rotations(7, rng)
        fit = opt.fit_gd(p, s, R0, opt.initial_translations(s, 0.2), 50, 0.01, 1.0, "float64")
        buffer = io.BytesIO()
        np.save(buffer, fit.poses)
        sys.stdout.buffer.write(buffer.getvalue())
        """
    )
    root = Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, check=True, env={"PYTHONPATH": str(root), "PATH": ""})
    sharded = np.load(io.BytesIO(out.stdout))
    rng = np.random.default_rng(0)
    p = rng.normal(scale=0.05, size=(7, 3, 3))
    s = p[0] + 0.1
    R0 = g.random_rotations(7, rng)
    single = opt.fit_gd(p, s, R0, opt.initial_translations(s, 0.2), 50, 0.01, 1.0, "float64")
    np.testing.assert_allclose(sharded, single.poses, atol=1e-9)


# --- orientation-aware fast solver (optimize.normal_weight) ------------------------------------


def _normal_scene(rng, n_sensors):
    """Box points with their face normals (object frame), a true pose, the world points and normals."""
    p = rng.uniform(-HALF, HALF, (n_sensors, 3))
    axis = rng.integers(0, 3, n_sensors)
    sign = np.where(rng.random(n_sensors) < 0.5, -1.0, 1.0)
    p[np.arange(n_sensors), axis] = sign * HALF[axis]
    n = np.zeros((n_sensors, 3))
    n[np.arange(n_sensors), axis] = sign
    T = g.make_pose(g.random_rotations(1, rng)[0], rng.uniform(-0.3, 0.3, 3))
    return p, n, g.transform_points(T, p), n @ T[:3, :3].T, T


@pytest.mark.parametrize("n_sensors", [2, 3, 4])
def test_normal_term_recovers_the_pose_that_positions_leave_free(n_sensors):
    rng = np.random.default_rng(10 + n_sensors)
    for _ in range(10):
        p, n, s, m, T = _normal_scene(rng, n_sensors)
        if n_sensors == 2 and abs(abs(np.dot(n[0], n[1])) - 1) < 1e-9 and abs(np.dot(n[0], p[1] - p[0])) > 0.999 * np.linalg.norm(p[1] - p[0]):
            continue  # degenerate: both normals along the line through the points
        fit = opt.fit_fast(p[None], s, g.random_rotations(1, rng), 5, (n[None], m), 0.01)
        dt, dr = _errors(fit.poses[0], T)
        assert dt < 1e-3 and dr < 0.1
        assert fit.losses[0] < 1e-6
    if n_sensors == 2:
        # Without the normals the rotation about the line through the two points stays random.
        plain = opt.fit_fast(p[None], s, g.random_rotations(1, rng), 5)
        assert _errors(plain.poses[0], T)[1] > 1.0


def test_normal_term_with_one_sensor_turns_the_random_rotation_onto_the_normal():
    rng = np.random.default_rng(3)
    p, n, s, m, _T = _normal_scene(rng, 1)
    R0 = g.random_rotations(20, rng)
    fit = opt.fit_fast(np.repeat(p[None], 20, axis=0), s, R0, 5, (np.repeat(n[None], 20, axis=0), m), 0.01)
    np.testing.assert_allclose(np.einsum("nab,b->na", fit.poses[:, :3, :3], n[0]), np.repeat(m, 20, axis=0), atol=1e-9)
    np.testing.assert_allclose(fit.poses[:, :3, :3] @ p[0] + fit.poses[:, :3, 3], np.repeat(s, 20, axis=0), atol=1e-12)
    assert np.all(fit.losses < 1e-9)


def test_normal_term_prefers_the_tuple_whose_normals_agree():
    # Two tuples with the same points (same position loss); one has a flipped normal: its loss is higher.
    rng = np.random.default_rng(4)
    p, n, s, m, _T = _normal_scene(rng, 3)
    bad = n.copy()
    bad[0] *= -1
    fit = opt.fit_fast(np.stack([p, p]), s, g.random_rotations(2, rng), 5, (np.stack([n, bad]), m), 0.01)
    assert fit.losses[0] < 1e-6 and fit.losses[1] > 1e-3
    with pytest.raises(InputError):
        opt.tuples_to_poses(p, s, np.array([[0, 1, 2]]), "fast", rng, normal_weight=0.01)


def _least_squares_pose(p, s):
    """The naive least-squares rigid fit (Arun et al.'s SVD, reflection guarded): the reference for a fit
    whose residuals are all below the noise floor."""
    pc, sc = p - p.mean(0), s - s.mean(0)
    u, _, vt = np.linalg.svd(sc.T @ pc)
    d = np.sign(np.linalg.det(u @ vt))
    R = u @ np.diag([1.0, 1.0, d]) @ vt
    return g.make_pose(R, s.mean(0) - R @ p.mean(0))


def test_residuals_below_the_noise_floor_are_fitted_in_least_squares():
    rng = np.random.default_rng(7)
    for n_sensors in (3, 4):
        p, s, _ = _scene(rng, n_sensors, noise=0.002)
        rotations = np.eye(3)[None]
        # A floor above every residual: every IRLS weight is the same, the fit is least squares.
        floored = opt.fit_fast(p[None], s, rotations, n_irls=5, noise=(0.05, 0.0))
        np.testing.assert_allclose(floored.poses[0], _least_squares_pose(p, s), atol=1e-12)
        # The loss reported is still the paper's mean of plain distances, at that pose.
        assert floored.losses[0] == pytest.approx(opt.poses_to_losses(floored.poses, p[None], s)[0])
        # No noise: the plain-distance IRLS as before, which reaches a lower E than least squares.
        plain = opt.fit_fast(p[None], s, rotations, n_irls=5)
        np.testing.assert_array_equal(opt.fit_fast(p[None], s, rotations, n_irls=5, noise=(0.0, 0.0)).poses, plain.poses)
        assert plain.losses[0] < floored.losses[0]
        # A floor between: residuals under it weigh alike, those above it less, so the fit lies between.
        some = opt.fit_fast(p[None], s, rotations, n_irls=5, noise=(0.001, 0.0))
        assert plain.losses[0] <= some.losses[0] <= floored.losses[0] + 1e-12


def test_the_optimize_step_floors_the_fit_at_the_sensors_contact_error():
    from tactile6d.core.config import default_section
    from tactile6d.core.settings import OptimizeSettings, SensorSettings
    from tactile6d.estimation.optimize import optimize
    from tactile6d.perception.contacts import Contacts

    rng = np.random.default_rng(8)
    p, s, _ = _scene(rng, 3, noise=0.002)
    contacts = Contacts(s, np.tile([0.0, 0.0, -1.0], (3, 1)), np.zeros(3, bool))
    settings = OptimizeSettings.from_cfg({**default_section("optimize"), "noise_floor": True})

    def fit(mm, deg, settings=settings):
        sensors = SensorSettings.from_cfg({"pose_sigma_mm": mm, "pose_sigma_deg": deg})
        return optimize(p, contacts, np.arange(3)[None], settings, sensors=sensors).poses[0]

    # Exact sensor poses: the paper's plain-distance IRLS; sensor poses off by 20 mm (a floor above every
    # residual here): least squares.
    plain = opt.fit_fast(p[None], s, np.eye(3)[None], settings.n_irls).poses[0]
    np.testing.assert_allclose(fit(0, 0), plain, atol=1e-12)
    np.testing.assert_allclose(fit(20, 0), _least_squares_pose(p, s), atol=1e-12)
    # The default leaves the floor off (not adopted): plain distances whatever the sensors' error.
    default = OptimizeSettings.from_cfg(default_section("optimize"))
    assert not default.noise_floor
    np.testing.assert_allclose(fit(20, 0, default), plain, atol=1e-12)
