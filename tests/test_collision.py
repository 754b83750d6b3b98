import functools

import numpy as np
import pytest
import trimesh

from tactile6d.core import geometry as g
from tactile6d.core import sensor as sn
from tactile6d.core.errors import InputError, MeshError
from tactile6d.estimation import collision as col
from tactile6d.estimation import rank as rk

CUBE = trimesh.creation.box(extents=[0.05, 0.05, 0.05])


def _cube_model():
    return col.PenetrationModel(col.vertices_to_pieces([CUBE.vertices]))


def _sensor_pose(rng):
    return g.make_pose(g.random_rotations(1, rng)[0], rng.uniform(-0.2, 0.2, 3))


def _cube_against_box_face(T_world_sensor, depth, axis=0, side=1.0):
    """The 5 cm cube posed (aligned with the sensor box) so that it overlaps the box's face on
    ``axis`` (side +-1) by ``depth`` (negative: a gap), offset sideways so that no edge lines up."""
    offset = np.array([0.003, -0.002, 0.004])
    offset[axis] = side * (sn.BOX_HALF_EXTENTS[axis] + 0.025 - depth)
    return T_world_sensor @ g.make_pose(np.eye(3), sn.BOX_CENTER + offset)


@pytest.mark.parametrize("depth", [0.0003, 0.001, 0.002, 0.005])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_box_overlap_depth_is_measured(depth, axis):
    rng = np.random.default_rng(axis)
    model = _cube_model()
    T_sensor = _sensor_pose(rng)
    for side in (1.0, -1.0):
        T_obj = _cube_against_box_face(T_sensor, depth, axis, side)
        d = col.poses_to_penetrations(model, T_obj[None], T_sensor[None])
        assert d.shape == (1, 1)
        assert abs(d[0, 0] - depth) < 1e-6


def _sat_depth(R, t, half_a, half_b):
    """Exact penetration depth of box b (pose R, t in box a's frame) into box a: the least overlap
    over the 15 separating axes (3 + 3 face normals, 9 edge cross products)."""
    axes = list(np.eye(3)) + list(R.T)
    for a in np.eye(3):
        for b in R.T:
            c = np.cross(a, b)
            if np.linalg.norm(c) > 1e-9:
                axes.append(c / np.linalg.norm(c))
    overlaps = [np.sum(half_a * np.abs(n)) + np.sum(half_b * np.abs(R.T @ n)) - abs(t @ n) for n in axes]
    return max(min(overlaps), 0.0)


@pytest.mark.slow
def test_depth_matches_the_separating_axis_answer_for_rotated_boxes():
    rng = np.random.default_rng(4)
    model = _cube_model()
    errors = []
    while len(errors) < 150:
        R = g.random_rotations(1, rng)[0]
        t = rng.normal(size=3)
        t *= rng.uniform(0.01, 0.06) / np.linalg.norm(t)
        exact = _sat_depth(R, t, sn.BOX_HALF_EXTENTS, np.full(3, 0.025))
        if 0 < exact <= 0.01:
            errors.append(model.depth(0, g.make_pose(R, t)) - exact)
        args = (model.pieces, g.make_pose(R, t)[None], np.linalg.inv(g.make_pose(np.eye(3), sn.BOX_CENTER))[None])
        assert col.poses_to_vertex_depth_bounds(*args)[0, 0] <= exact + 1e-12
        assert col.poses_to_box_depth_bounds(*args)[0, 0] <= exact + 1e-12
    errors = np.abs(errors)
    # EPA is exact to micrometres on most contacts and rarely off by up to ~2 mm (module docstring).
    assert np.median(errors) < 1e-5 and np.quantile(errors, 0.9) < 1e-4


def test_depth_is_zero_when_apart_near_or_far():
    rng = np.random.default_rng(0)
    model = _cube_model()
    T_sensor = _sensor_pose(rng)
    near = _cube_against_box_face(T_sensor, -0.002)  # 2 mm gap: fcl is called and says apart
    far = T_sensor @ g.make_pose(np.eye(3), [0.5, 0, 0])  # screened out by the bounding sphere
    np.testing.assert_array_equal(col.poses_to_penetrations(model, np.stack([near, far]), T_sensor[None]), 0.0)


def test_screening_changes_nothing_and_pieces_combine_by_max():
    rng = np.random.default_rng(1)
    two = [CUBE.vertices, CUBE.vertices + [0.05, 0, 0]]  # two cubes side by side
    model = col.PenetrationModel(col.vertices_to_pieces(two))
    T_sensors = np.stack([_sensor_pose(rng) for _ in range(2)])
    # Poses scattered around the first sensor's box, many touching it.
    T_obj = T_sensors[0] @ g.make_pose(g.random_rotations(60, rng), rng.normal(scale=0.04, size=(60, 3)))
    depths = col.poses_to_penetrations(model, T_obj, T_sensors)
    relative = col.object_to_box_poses(T_obj, T_sensors)
    # Every piece queried, at the very same relative poses (EPA's answer can move by a fraction of
    # a millimetre with the last bits of a pose).
    naive = np.array([[max(model.depth(k, rel) for k in range(2)) for rel in row] for row in relative])
    bounds = np.maximum(
        col.poses_to_vertex_depth_bounds(model.pieces, T_obj, T_sensors),
        col.poses_to_box_depth_bounds(model.pieces, T_obj, T_sensors),
    )
    np.testing.assert_array_equal(depths, np.maximum(naive, bounds))
    np.testing.assert_allclose(relative, [[g.invert_pose(Tb) @ To for Tb in col.sensor_box_poses(T_sensors)] for To in T_obj], atol=1e-15)
    assert np.sum(depths[:, 0] > 0) > 10


def test_hull_of_a_non_convex_input_and_degenerate_pieces():
    pieces = col.vertices_to_pieces([np.vstack([CUBE.vertices, [[0, 0, 0]]])])
    assert len(pieces.vertices[0]) == 8
    np.testing.assert_allclose(pieces.radii, np.sqrt(3) * 0.025)
    with pytest.raises(MeshError):
        col.vertices_to_pieces([np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])])
    with pytest.raises(MeshError):
        col.vertices_to_pieces([np.zeros((3, 3))])


def _touching_scene():
    """A 10 x 6 x 16 cm box touched on three faces by sensors pressed 1.8 mm in (the default)."""
    box = trimesh.creation.box(extents=[0.1, 0.06, 0.16])
    points = np.array([[0.05, 0.01, 0.02], [-0.05, -0.01, 0.0], [0.0, 0.03, -0.03]])
    normals = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0]])
    T_world_object = g.make_pose(g.rotvec_to_rotmat([0.2, -0.4, 1.0]), [0.1, 0, 0.2])
    T_world_sensor = T_world_object @ sn.sensor_poses_touching(points, normals)
    return col.PenetrationModel(col.vertices_to_pieces([box.vertices])), T_world_object, T_world_sensor


def test_touching_sensors_do_not_penetrate_and_a_shifted_pose_does():
    model, T_true, T_sensors = _touching_scene()
    np.testing.assert_array_equal(col.poses_to_penetrations(model, T_true[None], T_sensors), 0.0)
    shifted = T_true.copy()
    shifted[:3, 3] -= 0.004 * T_sensors[0, :3, 0]  # 4 mm toward the sensor's camera, through the gel
    d = col.poses_to_penetrations(model, shifted[None], T_sensors)[0]
    # The box's face is 0.6 mm in front of the sensor box when touching, so 4 mm in gives 3.4 mm.
    assert d[0] == pytest.approx(0.0034, abs=1e-6) and d[1] == 0


def test_penetrating_pose_ranks_below_a_touching_one():
    model, T_true, T_sensors = _touching_scene()
    shifted = T_true.copy()
    shifted[:3, 3] -= 0.004 * T_sensors[0, :3, 0]
    score = functools.partial(col.poses_to_penetrations, model, T_world_sensor=T_sensors)
    # The penetrating pose has the lower loss, yet the touching one wins.
    ranked = rk.rank_poses(np.stack([shifted, T_true]), np.array([0.001, 0.002]), score, 2, 0.001, 0.01)
    np.testing.assert_array_equal(ranked.index, [1, 0])
    np.testing.assert_allclose(ranked.scores, [0.002, 0.001 + 0.0034], atol=1e-6)
    assert ranked.penetrations.shape == (2, 3)
    # With an allowance of the sensor poses' expected error (sensors.pose_sigma_*), a penetration within it
    # costs nothing: the lower loss wins; the depths reported stay the penetrations themselves.
    allowed = rk.rank_poses(np.stack([shifted, T_true]), np.array([0.001, 0.002]), score, 2, 0.001, 0.01,
                            allowance=0.0035)
    np.testing.assert_array_equal(allowed.index, [0, 1])
    np.testing.assert_allclose(allowed.scores, [0.001, 0.002], atol=1e-6)
    np.testing.assert_array_equal(allowed.penetrations, ranked.penetrations[::-1])


@pytest.mark.slow
def test_the_penetration_allowance_follows_the_sensor_pose_sigmas():
    from tactile6d.core.config import compose_config
    from tactile6d.core.sensor import GEL_CENTER
    from tactile6d.core.settings import SensorSettings

    def allowance(mm, deg):
        return SensorSettings.from_cfg(compose_config([f"sensors.pose_sigma_mm={mm}",
                                                       f"sensors.pose_sigma_deg={deg}"]).sensors).contact_sigma

    assert allowance(0, 0) == 0.0 and allowance(1.5, 0) == pytest.approx(0.0015)
    assert allowance(0, 1.0) == pytest.approx(np.linalg.norm(GEL_CENTER) * np.radians(1.0))
    assert allowance(1.5, 1.5) == pytest.approx(np.hypot(0.0015, np.linalg.norm(GEL_CENTER) * np.radians(1.5)))
    np.testing.assert_allclose(rk.penetration_cost(np.array([[0.001, 0.003], [0.0, 0.0005]]), 0.002), [0.001, 0.0])


@pytest.mark.slow
def test_the_sensor_pose_sigmas_switch_the_sensor_corrections():
    from tactile6d.core.config import compose_config
    from tactile6d.core.settings import Settings

    def settings(*overrides):
        return Settings.from_cfg(compose_config(list(overrides)))

    default = settings()
    # The default is a hand's kinematics, not exact poses; the paper's method takes the poses as exact.
    sensors = default.sensors
    assert sensors.pose_sigma_mm > 0 and sensors.pose_sigma_deg > 0 and default.corrects_sensors
    assert sensors.correction_sigmas == pytest.approx((sensors.contact_sigma, np.radians(sensors.pose_sigma_deg)))
    paper = settings("preset=paper")
    assert paper.sensors.exact and paper.sensors.contact_sigma == 0.0 and not paper.corrects_sensors
    assert not settings("sensors.pose_sigma_mm=0", "sensors.pose_sigma_deg=0").corrects_sensors
    assert not settings("rank.refine=false").corrects_sensors
    # One sigma alone still corrects; the other part of the pose is then held (nearly) exact.
    only_mm = settings("sensors.pose_sigma_mm=1", "sensors.pose_sigma_deg=0")
    assert only_mm.corrects_sensors and only_mm.sensors.correction_sigmas[1] < np.radians(0.01)
    with pytest.raises(Exception, match="pose_correction_weight"):
        settings("rank.pose_correction_weight=-1")
    with pytest.raises(Exception, match="sensors.pose_sigma_mm"):
        settings("sensors.pose_sigma_mm=-1")



def rank_poses_brute_force(poses, losses, penetrations, top_k, tol_translation, tol_rotation, allowance=0.0):
    """The naive reference for ``rank.rank_poses``: score every pose, then de-duplicate and take the top k."""
    depths = np.asarray(penetrations(poses), dtype=np.float64)
    scores = losses + rk.penetration_cost(depths, allowance)
    kept = rk.distinct_in_order(poses, np.lexsort((np.arange(len(scores)), scores)), tol_translation, tol_rotation,
                                top_k)
    return rk.RankedPoses(poses[kept], scores[kept], losses[kept], depths[kept], np.asarray(kept, dtype=np.int64),
                          len(poses))

@pytest.mark.slow
def test_lazy_ranking_equals_scoring_everything():
    rng = np.random.default_rng(3)
    model, T_true, T_sensors = _touching_scene()
    n = 400
    # Hypotheses around the truth, with clusters of near-duplicates, and random losses.
    base = T_true @ g.make_pose(g.rotvec_to_rotmat(rng.normal(scale=0.1, size=(40, 3))), rng.normal(scale=0.006, size=(40, 3)))
    jitter = g.make_pose(g.rotvec_to_rotmat(rng.normal(scale=0.005, size=(n, 3))), rng.normal(scale=0.001, size=(n, 3)))
    poses = base[rng.integers(0, 40, n)] @ jitter
    losses = rng.uniform(0, 0.01, n)
    calls = []

    def score(T):
        calls.append(len(T))
        return col.poses_to_penetrations(model, T, T_sensors)

    n_scored = []
    bounds = [
        functools.partial(col.poses_to_vertex_depth_bounds, model.pieces, T_world_sensor=T_sensors),
        functools.partial(col.poses_to_box_depth_bounds, model.pieces, T_world_sensor=T_sensors),
    ]
    for top_k, tol_t, tol_r, lb in [(5, 0.005, np.radians(5), ()), (1, 0.0, 0.0, ()), (12, 0.01, 0.2, ()), (5, 0.005, 0.1, bounds)]:
        calls.clear()
        lazy = rk.rank_poses(poses, losses, score, top_k, tol_t, tol_r, depth_bounds=lb, batch=16)
        assert lazy.n_scored == sum(calls)
        full = rank_poses_brute_force(poses, losses, score, top_k, tol_t, tol_r)
        np.testing.assert_array_equal(lazy.index, full.index)
        allowed = rk.rank_poses(poses, losses, score, top_k, tol_t, tol_r, depth_bounds=lb, batch=16, allowance=0.002)
        allowed_full = rank_poses_brute_force(poses, losses, score, top_k, tol_t, tol_r, allowance=0.002)
        np.testing.assert_array_equal(allowed.index, allowed_full.index)
        np.testing.assert_array_equal(allowed.scores, allowed_full.scores)
        np.testing.assert_array_equal(lazy.scores, full.scores)
        np.testing.assert_array_equal(lazy.penetrations, full.penetrations)
        assert np.all(np.diff(lazy.scores) >= 0) and len(lazy.index) == top_k
        n_scored.append(lazy.n_scored)
    assert n_scored[0] < n and n_scored[1] < n and n_scored[3] < n
    # fcl's depths alone, raised by rank_poses to the bounds it computed, as the rank step scores them.
    fcl_only = functools.partial(col.poses_to_fcl_depths, model, T_world_sensor=T_sensors)
    lazy = rk.rank_poses(poses, losses, fcl_only, 5, 0.005, 0.1, depth_bounds=bounds, batch=16)
    full = rank_poses_brute_force(poses, losses, score, 5, 0.005, 0.1)
    np.testing.assert_array_equal(lazy.index, full.index)
    np.testing.assert_array_equal(lazy.penetrations, full.penetrations)


def test_near_duplicates_collapse():
    T = g.make_pose(np.eye(3), [0, 0, 0])
    poses = np.stack([T, T @ g.make_pose(g.rotvec_to_rotmat([0, 0, 0.02]), [0.002, 0, 0]), T @ g.make_pose(np.eye(3), [0.02, 0, 0])])
    kept = rk.distinct_in_order(poses, np.arange(3), 0.005, np.radians(5), 5)
    assert kept == [0, 2]
    assert rk.distinct_in_order(poses, np.arange(3), 0.001, np.radians(5), 5) == [0, 1, 2]
    assert rk.distinct_in_order(poses, np.array([2, 1, 0]), 0.005, np.radians(5), 1) == [2]


def distinct_in_order_reference(poses, order, tol_translation, tol_rotation, limit):
    """The greedy de-duplication pose by pose: the definition ``ranking.distinct_in_order`` vectorises."""
    kept = []
    for j in order:
        if kept:
            near_t = np.linalg.norm(poses[kept, :3, 3] - poses[j, :3, 3], axis=1) <= tol_translation
            if np.any(near_t):
                candidates = np.asarray(kept)[near_t]
                if np.any(g.rotation_angle(poses[candidates, :3, :3], poses[j, :3, :3]) <= tol_rotation):
                    continue
        kept.append(int(j))
        if len(kept) == limit:
            break
    return kept


@pytest.mark.parametrize("seed", range(6))
def test_distinct_in_order_matches_the_pose_by_pose_walk(seed):
    # Tight clusters around a few poses, as the optimiser's hypotheses come, with some spread far enough
    # to be distinct in translation only, in rotation only, or in both.
    rng = np.random.default_rng(seed)
    centres = [g.make_pose(g.rotvec_to_rotmat(rng.normal(size=3)), rng.normal(scale=0.02, size=3)) for _ in range(6)]
    poses = np.stack([
        centres[rng.integers(6)] @ g.make_pose(g.rotvec_to_rotmat(rng.normal(scale=0.06, size=3)),
                                               rng.normal(scale=0.004, size=3))
        for _ in range(400)
    ])
    order = rng.permutation(len(poses))[: 350 if seed % 2 else 400]
    for limit in (1, 5, 30, 400):
        expected = distinct_in_order_reference(poses, order, 0.005, np.radians(5), limit)
        assert rk.distinct_in_order(poses, order, 0.005, np.radians(5), limit) == expected
    assert 5 < len(expected) < len(order)  # the clusters make the walk skip many, and keep several


def test_ranking_rejects_bad_input():
    with pytest.raises(InputError):
        rk.rank_poses(np.zeros((0, 4, 4)), np.zeros(0), lambda T: np.zeros((len(T), 1)), 5, 0.005, 0.1)
    with pytest.raises(InputError):
        rk.rank_poses(np.eye(4)[None], np.zeros(1), lambda T: np.zeros((len(T), 1)), 0, 0.005, 0.1)
