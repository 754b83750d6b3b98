import itertools
import warnings

import numpy as np
import pytest

from tactile6d.core import geometry as g
from tactile6d.core.errors import InputError, NoMatch
from tactile6d.estimation import select as sel

SELECT = {"delta_start": 5e-3, "step_down": 5e-4, "step_up": 1e-4, "delta_max": 5e-2}


def _box_surface_points(n, rng, size=(0.1, 0.06, 0.16)):
    """n points on the surface of a box (m), a stand-in for a database of an object's surface."""
    half = np.asarray(size) / 2
    p = rng.uniform(-half, half, size=(n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -1, 1) * half[axis]
    return p


def _scene(rng, n_points, n_sensors, noise=0.0):
    """Database points, the true tuple and the sensor points of a random pose of the object."""
    points = _box_surface_points(n_points, rng)
    true = rng.choice(n_points, n_sensors, replace=False)
    T = g.make_pose(g.random_rotations(1, rng)[0], rng.uniform(-0.3, 0.3, 3))
    s = g.transform_points(T, points[true]) + rng.normal(scale=noise, size=(n_sensors, 3))
    return points, true, s


def _reference_rule(points, s, omegas, n_max, delta_start, step_down, step_up, delta_max):
    """The reference code's loop, literally, on brute-force counts."""
    delta, raised = delta_start, False
    while True:
        tuples, errors = sel.tuples_within_brute_force(points, s, omegas, delta)
        n = tuples.shape[0]
        if 0 < n <= n_max or (n > n_max and raised):
            return delta, tuples, errors
        if n == 0:
            delta, raised = round(delta + step_up, 12), True
            assert delta <= delta_max
        else:
            delta = round(delta - step_down, 12)


def test_pair_distances_match_numpy_norm():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(7, 1, 3))
    np.testing.assert_allclose(sel.pair_distances(a, b), np.linalg.norm(a - b, axis=-1), rtol=1e-15)
    assert float(sel.pair_distances(a[0], b[0, 0])) == pytest.approx(np.linalg.norm(a[0] - b[0, 0]))


@pytest.mark.parametrize("n_sensors", [1, 2, 3, 4])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pruned_join_equals_brute_force(n_sensors, seed):
    rng = np.random.default_rng(seed)
    points, _true, s = _scene(rng, 60, n_sensors, noise=0.002)
    sizes = {1: 60, 2: 50, 3: 30, 4: 12}[n_sensors]
    omegas = [rng.choice(60, sizes, replace=False) for _ in range(n_sensors)]
    for delta in (1e-4, 1e-3, 4e-3, 2e-2, 0.2):
        fast = sel.tuples_within(points, s, omegas, delta)
        slow = sel.tuples_within_brute_force(points, s, omegas, delta)
        np.testing.assert_array_equal(fast[0], slow[0])
        np.testing.assert_array_equal(fast[1], slow[1])


def test_pruned_join_keeps_a_tuple_exactly_at_the_float32_rounding_edge():
    # Sensor distances chosen equal to database distances, so errors are exactly 0 for the true
    # tuple and near the threshold for many others: the float32 pruning must still not drop any.
    rng = np.random.default_rng(5)
    points, _true, s = _scene(rng, 80, 3)
    omegas = [np.arange(80)] * 3
    errors = sel.tuples_within_brute_force(points, s, omegas, 1.0)[1]
    for delta in np.quantile(errors, [1e-4, 1e-3, 1e-2]):
        edge = np.nextafter(delta, np.inf)  # the tuple with error == delta passes at this threshold
        fast = sel.tuples_within(points, s, omegas, edge)
        slow = sel.tuples_within_brute_force(points, s, omegas, edge)
        np.testing.assert_array_equal(fast[0], slow[0])


@pytest.mark.parametrize("n_max", [1, 40, 500, 100000])
@pytest.mark.parametrize("seed", [0, 3])
def test_adaptive_threshold_follows_the_reference_rule(n_max, seed):
    rng = np.random.default_rng(seed)
    points, _true, s = _scene(rng, 120, 3, noise=0.001)
    omegas = [rng.choice(120, 40, replace=False) for _ in range(3)]
    result = sel.select_tuples(points, s, omegas, n_max, rng=rng, **SELECT)
    delta, tuples, errors = _reference_rule(points, s, omegas, n_max, **SELECT)
    assert result.delta_d == pytest.approx(delta, abs=1e-12)
    if tuples.shape[0] <= n_max:
        assert not result.capped
        np.testing.assert_array_equal(result.tuples, tuples)
    else:
        # The reference keeps them all; the n_max lowest errors are kept here.
        assert result.capped and result.tuples.shape[0] == n_max
        assert result.errors.max() <= np.sort(errors)[n_max - 1]
        assert set(map(tuple, result.tuples)) <= set(map(tuple, tuples))


@pytest.mark.slow
def test_raising_past_n_max_keeps_the_lowest_errors_ties_by_index():
    # Every point twice: tuples come in groups of equal error, so the count jumps from 0 past n_max = 3.
    rng = np.random.default_rng(3)
    points, _true, s = _scene(rng, 40, 3, noise=0.001)
    points = np.concatenate([points, points])
    omegas = [np.arange(80)] * 3
    result = sel.select_tuples(points, s, omegas, 3, rng=rng, **SELECT)
    delta, tuples, errors = _reference_rule(points, s, omegas, 3, **SELECT)
    assert result.capped and result.delta_d == pytest.approx(delta, abs=1e-12) and tuples.shape[0] > 3
    order = np.lexsort(tuple(tuples.T[::-1]) + (errors,))[:3]
    np.testing.assert_array_equal(result.tuples, tuples[np.sort(order)])


@pytest.mark.parametrize("n_sensors", [2, 3, 4])
def test_true_tuple_survives_when_each_omega_contains_its_point(n_sensors):
    for seed in range(5):
        rng = np.random.default_rng(seed)
        points, true, s = _scene(rng, 400, n_sensors)
        omegas = [np.union1d(rng.choice(400, 80, replace=False), [t]) for t in true]
        result = sel.select_tuples(points, s, omegas, 200, rng=rng, **SELECT)
        assert any(np.array_equal(row, true) for row in result.tuples)
        assert result.tuples.shape[0] <= 200


def test_baseline_uses_all_points_without_materialising_the_product():
    # 600^3 = 2e8 triples, too many to enumerate in a test's memory; the join handles it.
    rng = np.random.default_rng(7)
    points, true, s = _scene(rng, 600, 3)
    omegas = sel.all_points_omegas(600, 3)
    result = sel.select_tuples(points, s, omegas, 5000, rng=rng, **SELECT)
    assert 0 < result.tuples.shape[0] <= 5000
    assert any(np.array_equal(row, true) for row in result.tuples)
    np.testing.assert_array_equal(result.errors, sel.tuples_to_errors(points, s, result.tuples))
    assert np.all(result.errors < result.delta_d)


def test_single_sensor_keeps_every_point_then_caps_at_random():
    rng = np.random.default_rng(0)
    points = _box_surface_points(50, rng)
    s = points[:1]
    result = sel.select_tuples(points, s, [np.arange(10, 40)], 100, rng=rng, **SELECT)
    np.testing.assert_array_equal(result.tuples[:, 0], np.arange(10, 40))
    assert not result.capped and np.all(result.errors == 0)
    capped = sel.select_tuples(points, s, [np.arange(10, 40)], 7, rng=rng, **SELECT)
    assert capped.capped and capped.tuples.shape == (7, 1)
    assert np.all(np.diff(capped.tuples[:, 0]) > 0) and np.isin(capped.tuples, np.arange(10, 40)).all()


def test_impossible_distances_are_no_match_not_bad_input():
    rng = np.random.default_rng(0)
    points = _box_surface_points(30, rng)
    s = np.array([[0.0, 0, 0], [5.0, 0, 0]])  # 5 m apart: no pair of points on a 16 cm box
    for rule in ("paper", "best_n"):
        with pytest.raises(NoMatch, match="no tuple") as info:
            sel.select_tuples(points, s, [np.arange(30)] * 2, 10, rng=rng, **{**SELECT, "rule": rule})
        assert not isinstance(info.value, InputError)


def test_angles_to_omegas_thresholds_each_sensor():
    a_db = np.linspace(0.0, 1.0, 101)
    result = sel.angles_to_omegas(a_db, np.array([0.2, 0.9]), 0.025, 0.01, 0.5)
    np.testing.assert_array_equal(result.omegas[0], np.arange(18, 23))
    np.testing.assert_array_equal(result.omegas[1], np.arange(88, 93))
    np.testing.assert_array_equal(result.delta_h, [0.025, 0.025])


def test_empty_omega_widens_delta_h_with_a_warning():
    a_db = np.array([0.0, 0.1, 0.5])
    with pytest.warns(UserWarning, match="sensor 1"):
        result = sel.angles_to_omegas(a_db, np.array([0.1, 0.3]), 0.05, 0.02, 1.0)
    np.testing.assert_array_equal(result.omegas[0], [1])
    # nearest angle is 0.2 away: 0.05 + 8 * 0.02 = 0.21 is the first grid threshold above it
    assert result.delta_h[1] == pytest.approx(0.21)
    np.testing.assert_array_equal(result.omegas[1], [1, 2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NoMatch, match="sensor 1"):
            sel.angles_to_omegas(a_db, np.array([0.1, 0.3]), 0.05, 0.02, 0.1)


def test_bad_inputs_are_rejected():
    rng = np.random.default_rng(0)
    points = _box_surface_points(10, rng)
    with pytest.raises(InputError):
        sel.tuples_within(points, points[:2], [np.arange(10)], 1e-3)
    with pytest.raises(InputError):
        sel.tuples_within(points, points[:2], [np.arange(10), np.array([], dtype=int)], 1e-3)
    with pytest.raises(InputError):
        sel.tuples_within(points, points[:2], [np.arange(10), np.array([10])], 1e-3)


# --- rule best_n ---------------------------------------------------------------------------------


def _brute_lowest(points, s, omegas, n, normals=None, delta_max=SELECT["delta_max"]):
    tuples, errors = sel.tuples_within_brute_force(points, s, omegas, delta_max, normals)
    order = np.lexsort(tuple(tuples.T[::-1]) + (errors,))[:n]
    keep = tuples[np.sort(order)]
    return keep, errors[np.sort(order)], tuples.shape[0]


@pytest.mark.parametrize("n_sensors", [2, 3, 4])
@pytest.mark.parametrize("n_max", [1, 37, 500])
def test_best_n_keeps_exactly_the_n_lowest_errors(n_sensors, n_max):
    rng = np.random.default_rng(n_max + n_sensors)
    points, _true, s = _scene(rng, 80, n_sensors, noise=0.002)
    size = {2: 60, 3: 30, 4: 12}[n_sensors]
    omegas = [rng.choice(80, size, replace=False) for _ in range(n_sensors)]
    result = sel.select_tuples(points, s, omegas, n_max, rng=rng, rule="best_n", **SELECT)
    expected, errors, n_all = _brute_lowest(points, s, omegas, n_max)
    np.testing.assert_array_equal(result.tuples, expected)
    np.testing.assert_array_equal(result.errors, errors)
    assert result.capped == (n_all > n_max)
    assert result.delta_d == pytest.approx(errors.max())


def test_best_n_breaks_ties_by_index_order():
    rng = np.random.default_rng(3)
    points, _true, s = _scene(rng, 40, 3, noise=0.001)
    points = np.concatenate([points, points])  # every error appears (at least) twice
    omegas = [np.arange(80)] * 3
    for n_max in (3, 50):
        result = sel.select_tuples(points, s, omegas, n_max, rng=rng, rule="best_n", **SELECT)
        np.testing.assert_array_equal(result.tuples, _brute_lowest(points, s, omegas, n_max)[0])


def test_best_n_keeps_the_nearest_tuple_that_the_paper_rule_drops():
    # Sensors ~2 mm off the database points (true tuple error 1.5 mm): the paper's rule stops at
    # delta_d = 0.5 mm with ~600 chance near-congruent tuples and misses it; best_n keeps a superset
    # of those, and the true tuple once N reaches its rank.
    rng = np.random.default_rng(12)
    points, true, s = _scene(rng, 600, 3, noise=0.002)
    omegas = sel.all_points_omegas(600, 3)
    paper = sel.select_tuples(points, s, omegas, 5000, rng=rng, **SELECT)
    assert not paper.capped and not any(np.array_equal(row, true) for row in paper.tuples)
    best = sel.select_tuples(points, s, omegas, 5000, rng=rng, rule="best_n", **SELECT)
    assert best.tuples.shape[0] == 5000 and best.capped
    assert set(map(tuple, paper.tuples)) <= set(map(tuple, best.tuples))
    np.testing.assert_array_equal(best.errors, sel.tuples_to_errors(points, s, best.tuples))
    e_true = sel.tuples_to_errors(points, s, true[None])[0]
    rank = sel.tuples_within(points, s, omegas, np.nextafter(e_true, np.inf))[0].shape[0]
    enough = sel.select_tuples(points, s, omegas, rank, rng=rng, rule="best_n", **SELECT)
    assert any(np.array_equal(row, true) for row in enough.tuples)


@pytest.mark.parametrize("n_max", [1, 20, 300])
def test_best_n_is_exact_when_probes_stop_early(monkeypatch, n_max):
    # A badly fitting object: database points within about a centimetre, sensors 4.5 cm apart, so every
    # tuple's error lies in a narrow band. Raising delta_d finds none, then nearly all at once, and with
    # small join chunks that probe stops early (past 4 N tuples): the case the shrinking bound of
    # _best_n works from.
    monkeypatch.setattr(sel, "_JOIN_CHUNK", 50)
    rng = np.random.default_rng(n_max)
    points = rng.normal(scale=0.005, size=(60, 3))
    s = 0.045 / np.sqrt(3) * np.array([[1.0, 0, 0], [-0.5, np.sqrt(3) / 2, 0], [-0.5, -np.sqrt(3) / 2, 0]])
    omegas = [rng.choice(60, 40, replace=False) for _ in range(3)]
    probes = []
    real_join = sel._join

    def recording_join(*args, **kwargs):
        probes.append(found := real_join(*args, **kwargs))
        return found

    monkeypatch.setattr(sel, "_join", recording_join)
    result = sel.select_tuples(points, s, omegas, n_max, rng=rng, rule="best_n", **SELECT)
    assert any(not complete for _, _, complete in probes)  # the case under test did occur
    expected, errors, n_all = _brute_lowest(points, s, omegas, n_max)
    np.testing.assert_array_equal(result.tuples, expected)
    np.testing.assert_array_equal(result.errors, errors)
    assert result.capped == (n_all > n_max)


def test_best_n_with_fewer_tuples_than_n_keeps_all_below_delta_max():
    rng = np.random.default_rng(2)
    points, _true, s = _scene(rng, 20, 3)
    omegas = [np.arange(20)] * 3
    result = sel.select_tuples(points, s, omegas, 10**6, rng=rng, rule="best_n", **SELECT)
    expected, _, n_all = _brute_lowest(points, s, omegas, 10**6)
    assert not result.capped and result.tuples.shape[0] == n_all
    np.testing.assert_array_equal(result.tuples, expected)


def test_unknown_rule_is_rejected():
    rng = np.random.default_rng(0)
    points, _true, s = _scene(rng, 20, 3)
    with pytest.raises(InputError, match="rule"):
        sel.select_tuples(points, s, [np.arange(20)] * 3, 10, rng=rng, rule="nope", **SELECT)


# --- normal consistency --------------------------------------------------------------------------


def _box_points_normals(n, rng, size=(0.1, 0.06, 0.16)):
    half = np.asarray(size) / 2
    p = rng.uniform(-half, half, size=(n, 3))
    axis = rng.integers(0, 3, n)
    sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    p[np.arange(n), axis] = sign * half[axis]
    normals = np.zeros((n, 3))
    normals[np.arange(n), axis] = sign
    return p, normals


def _normal_scene(rng, n_points, n_sensors):
    points, normals = _box_points_normals(n_points, rng)
    true = rng.choice(n_points, n_sensors, replace=False)
    T = g.make_pose(g.random_rotations(1, rng)[0], rng.uniform(-0.3, 0.3, 3))
    s = g.transform_points(T, points[true])
    return points, normals, true, s, normals[true] @ T[:3, :3].T


@pytest.mark.parametrize("n_sensors", [2, 3, 4])
@pytest.mark.parametrize("seed", [0, 1])
def test_normal_consistent_join_equals_brute_force(n_sensors, seed):
    rng = np.random.default_rng(seed)
    points, normals, true, s, m = _normal_scene(rng, 60, n_sensors)
    check = sel.NormalCheck(normals, m, np.radians(20.0))
    size = {2: 50, 3: 30, 4: 12}[n_sensors]
    omegas = [np.union1d(rng.choice(60, size, replace=False), [t]) for t in true]
    for delta in (1e-3, 2e-2, 0.2):
        fast = sel.tuples_within(points, s, omegas, delta, check)
        slow = sel.tuples_within_brute_force(points, s, omegas, delta, check)
        np.testing.assert_array_equal(fast[0], slow[0])
        np.testing.assert_array_equal(fast[1], slow[1])
        assert any(np.array_equal(row, true) for row in fast[0])  # exact contacts: the true tuple passes
    for rule in ("paper", "best_n"):
        plain = sel.select_tuples(points, s, omegas, 10**6, rng=rng, rule="best_n", **SELECT)
        checked = sel.select_tuples(points, s, omegas, 10**6, rng=rng, rule="best_n", normals=check, **SELECT)
        assert checked.tuples.shape[0] < plain.tuples.shape[0]


def test_normal_check_keeps_the_true_tuple_and_drops_one_with_incompatible_normals():
    rng = np.random.default_rng(4)
    points, normals, true, s, m = _normal_scene(rng, 200, 3)
    check = sel.NormalCheck(normals, m, np.radians(15.0))
    assert sel.tuples_normal_consistent(points, s, true[None], check)[0]
    # The same points with one normal flipped: the distances still match exactly, the normals cannot.
    flipped = normals.copy()
    flipped[true[1]] *= -1
    assert not sel.tuples_normal_consistent(points, s, true[None], sel.NormalCheck(flipped, m, np.radians(15.0)))[0]
    omegas = [np.arange(200)] * 3
    kept = sel.select_tuples(points, s, omegas, 10, rng=rng, rule="best_n", normals=check, **SELECT)
    assert any(np.array_equal(row, true) for row in kept.tuples)
    dropped = sel.select_tuples(points, s, omegas, 10, rng=rng, rule="best_n",
                                normals=sel.NormalCheck(flipped, m, np.radians(15.0)), **SELECT)
    assert not any(np.array_equal(row, true) for row in dropped.tuples)
    assert np.all(sel.tuples_normal_consistent(points, s, kept.tuples, check))


# --- the sensor poses' error (sensors.pose_sigma_*) ----------------------------------------------


@pytest.mark.slow
def test_the_paper_rule_never_lowers_the_threshold_below_the_tolerance():
    # The scene of test_best_n_keeps_the_nearest_tuple_that_the_paper_rule_drops: the paper's rule stops at
    # 0.5 mm (592 tuples; at 1 mm, its next step up, 5009 pass). With sensor poses that may be off by 0.8 mm,
    # the threshold stays there: every tuple below it (2470), a superset of the paper's.
    rng = np.random.default_rng(12)
    points, true, s = _scene(rng, 600, 3, noise=0.002)
    omegas = sel.all_points_omegas(600, 3)
    paper = sel.select_tuples(points, s, omegas, 5000, rng=rng, **SELECT)
    assert paper.delta_d == pytest.approx(5e-4) and not paper.capped
    tolerant = sel.select_tuples(points, s, omegas, 5000, rng=rng, tolerance=8e-4, **SELECT)
    within = sel.tuples_within(points, s, omegas, 8e-4)[0]
    np.testing.assert_array_equal(tolerant.tuples, within)
    assert set(map(tuple, paper.tuples)) < set(map(tuple, tolerant.tuples)) and not tolerant.capped
    # More than N below the tolerance (the true tuple's error, 1.5 mm, is below 2 mm): the N lowest, as
    # best_n keeps them; with N large enough, the true tuple among them.
    capped = sel.select_tuples(points, s, omegas, 5000, rng=rng, tolerance=0.002, **SELECT)
    best = sel.select_tuples(points, s, omegas, 5000, rng=rng, rule="best_n", **SELECT)
    assert capped.capped and capped.tuples.shape[0] == 5000
    np.testing.assert_array_equal(capped.tuples, best.tuples)
    e_true = sel.tuples_to_errors(points, s, true[None])[0]
    n_below = sel.tuples_within(points, s, omegas, 0.002)[0].shape[0]
    assert e_true < 0.002
    enough = sel.select_tuples(points, s, omegas, n_below, rng=rng, tolerance=0.002, **SELECT)
    assert any(np.array_equal(row, true) for row in enough.tuples)
    assert not any(np.array_equal(row, true) for row in paper.tuples)
    # A tolerance below where the rule stops changes nothing; best_n keeps its N lowest whatever the tolerance.
    low = sel.select_tuples(points, s, omegas, 5000, rng=rng, tolerance=paper.delta_d / 2, **SELECT)
    np.testing.assert_array_equal(low.tuples, paper.tuples)
    best_tolerant = sel.select_tuples(points, s, omegas, 5000, rng=rng, rule="best_n", tolerance=0.002, **SELECT)
    np.testing.assert_array_equal(best_tolerant.tuples, best.tuples)
    with pytest.raises(InputError, match="tolerance"):
        sel.select_tuples(points, s, omegas, 5000, rng=rng, tolerance=-1e-3, **SELECT)


@pytest.mark.slow
def test_the_pose_sigma_settings_set_the_tolerances_as_documented():
    from tactile6d.core.config import compose_config
    from tactile6d.core.sensor import GEL_CENTER
    from tactile6d.core.settings import SensorSettings

    def sensors(mm, deg):
        cfg = compose_config([f"sensors.pose_sigma_mm={mm}", f"sensors.pose_sigma_deg={deg}"])
        return SensorSettings.from_cfg(cfg.sensors)

    lever = np.linalg.norm(GEL_CENTER)
    # A contact point is off by hypot(mm, lever x deg) per axis; two of them by sqrt(2) that along the line
    # between them; the tolerance is two standard deviations.
    assert sensors(1.5, 1.5).pair_distance_tolerance == pytest.approx(
        2 * np.sqrt(2) * np.hypot(0.0015, lever * np.radians(1.5)))
    assert sensors(3, 0).pair_distance_tolerance == pytest.approx(2 * np.sqrt(2) * 0.003)
    assert sensors(1.5, 1.5).pair_angle_tolerance == pytest.approx(2 * np.sqrt(2) * np.radians(1.5))
    assert sensors(0, 0).pair_distance_tolerance == 0 and sensors(0, 0).pair_angle_tolerance == 0
    assert sensors(0, 0).exact and not sensors(0, 0.5).exact
    # Monotone in both sigmas.
    assert sensors(1, 1).pair_distance_tolerance < sensors(2, 1).pair_distance_tolerance < sensors(2, 2).pair_distance_tolerance


def test_the_select_step_widens_the_normal_check_by_the_sensors_turn():
    from tactile6d.core.config import compose_config
    from tactile6d.core.settings import SelectSettings, SensorSettings
    from tactile6d.estimation.select import select
    from tactile6d.perception.contacts import Contacts

    # Two contacts on a box's top face 6 cm apart, both normals straight down the face's normal; the
    # database's points carry normals turned 47 deg and 0 deg: a pair angle 47 deg off, beyond the 45 deg
    # tolerance with exact sensor poses, within 45 + 2 sqrt(2) x 1.5 = 49.2 deg with a hand's kinematics.
    tilt = np.radians(47.0)
    points = np.array([[0.0, 0.0, 0.02], [0.06, 0.0, 0.02]])
    normals = np.array([[np.sin(tilt), 0.0, np.cos(tilt)], [0.0, 0.0, 1.0]])
    contacts = Contacts(points.copy(), -np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]), np.zeros(2, bool))
    cfg = compose_config(["select.method=baseline", "select.normal_tol_deg=45", "select.N=10"])
    settings = SelectSettings.from_cfg(cfg.select)

    def kept(mm, deg):
        sensors = SensorSettings.from_cfg({"pose_sigma_mm": mm, "pose_sigma_deg": deg})
        try:
            return select(points, None, contacts, None, settings, normals, sensors=sensors).tuples.tolist()
        except NoMatch:
            return []

    assert [0, 1] not in kept(0, 0)
    assert [0, 1] in kept(1.5, 1.5)


def _sphere_points(n, radius, rng):
    p = rng.normal(size=(n, 3))
    return radius * p / np.linalg.norm(p, axis=1, keepdims=True)


def test_a_join_over_its_check_budget_is_no_match_and_a_large_budget_changes_nothing():
    # Three sensors on a circle of radius 6 cm (a torus touched around its ring) against a sphere of radius 4 cm:
    # every sensor pair (10.4 cm apart) fits many point pairs of the sphere, no triple does (circumradius 6 > 4).
    rng = np.random.default_rng(3)
    points = _sphere_points(400, 0.04, rng)
    angles = np.radians([0.0, 120.0, 240.0])
    s = 0.06 * np.stack([np.cos(angles), np.sin(angles), np.zeros(3)], axis=1)
    omegas = [np.arange(400)] * 3
    settings = {**SELECT, "delta_max": 0.01, "rule": "best_n"}
    with pytest.raises(NoMatch, match="partial tuples to check"):
        sel.select_tuples(points, s, omegas, 50, rng=rng, max_checks=10_000, **settings)
    with pytest.raises(NoMatch, match="no tuple"):  # no budget: the same outcome, the whole join checked
        sel.select_tuples(points, s, omegas, 50, rng=rng, **settings)
    # A scene that does fit: a budget far above its work gives exactly the unbudgeted selection.
    box, _, s_box = _scene(np.random.default_rng(4), 300, 3)
    for rule in ("best_n", "paper"):
        free = sel.select_tuples(box, s_box, [np.arange(300)] * 3, 50, rng=rng, **{**SELECT, "rule": rule})
        capped = sel.select_tuples(box, s_box, [np.arange(300)] * 3, 50, rng=rng, max_checks=10**9,
                                   **{**SELECT, "rule": rule})
        np.testing.assert_array_equal(free.tuples, capped.tuples)
        np.testing.assert_array_equal(free.errors, capped.errors)


def _naive_beam(points, s, omegas, n_max, join_sensors, delta_max=SELECT["delta_max"]):
    """The beam of rule best_n beyond ``join_sensors`` sensors, with loops: the n_max best tuples of the
    join_sensors sensors with the fewest candidates (brute force), then each other sensor added in order of
    candidate count, keeping the n_max lowest summed pair errors (ties by partial tuple, then candidate),
    then the n_max lowest mean errors below delta_max (ties by index order)."""
    omegas = [np.unique(o) for o in omegas]
    by_size = sorted(range(len(omegas)), key=lambda i: (len(omegas[i]), i))
    core = sorted(by_size[:join_sensors])

    def pair_error(a, i, b, j):
        return abs(float(np.linalg.norm(points[i] - points[j])) - float(np.linalg.norm(s[a] - s[b])))

    core_tuples, core_errors = sel.tuples_within_brute_force(points, s[core], [omegas[c] for c in core], delta_max)
    order = np.lexsort(tuple(core_tuples.T[::-1]) + (core_errors,))[:n_max]
    beam = [dict(zip(core, row)) for row in core_tuples[np.sort(order)]]  # lexicographic order, as the join's
    sums = [sum(pair_error(a, t[a], b, t[b]) for a, b in itertools.combinations(core, 2)) for t in beam]
    for m in by_size[join_sensors:]:
        grown = []
        for p, (t, total) in enumerate(zip(beam, sums)):
            for j_pos, j in enumerate(omegas[m]):
                grown.append((total + sum(pair_error(a, t[a], m, j) for a in t), p * len(omegas[m]) + j_pos, {**t, m: j}))
        grown.sort(key=lambda x: (x[0], x[1]))
        beam, sums = [x[2] for x in grown[:n_max]], [x[0] for x in grown[:n_max]]
    tuples = np.array([[t[i] for i in range(len(omegas))] for t in beam])
    errors = sel.tuples_to_errors(points, s, tuples)
    keep = errors < delta_max
    order = np.lexsort(tuple(tuples[keep].T[::-1]) + (errors[keep],))[:n_max]
    chosen = tuples[keep][order]
    chosen = chosen[np.lexsort(chosen.T[::-1])]  # rows in lexicographic order, as every selection returns them
    return chosen, sel.tuples_to_errors(points, s, chosen)


@pytest.mark.parametrize("n_sensors,join_sensors", [(4, 3), (5, 3), (4, 2)])
@pytest.mark.parametrize("n_max", [1, 9, 60])
def test_best_n_beyond_join_sensors_is_the_naive_beam(n_sensors, join_sensors, n_max):
    rng = np.random.default_rng(10 * n_sensors + n_max)
    points, _true, s = _scene(rng, 50, n_sensors, noise=0.002)
    omegas = [rng.choice(50, size, replace=False) for size in rng.integers(6, 14, n_sensors)]
    result = sel.select_tuples(points, s, omegas, n_max, rng=rng, rule="best_n", join_sensors=join_sensors, **SELECT)
    expected, errors = _naive_beam(points, s, omegas, n_max, join_sensors)
    np.testing.assert_array_equal(result.tuples, expected)
    np.testing.assert_array_equal(result.errors, errors)
    assert result.delta_d == errors.max()


@pytest.mark.parametrize("n_sensors", [2, 3])
def test_join_sensors_leaves_three_sensors_or_fewer_exact(n_sensors):
    rng = np.random.default_rng(n_sensors)
    points, _true, s = _scene(rng, 80, n_sensors, noise=0.002)
    omegas = [rng.choice(80, 30, replace=False) for _ in range(n_sensors)]
    exact = sel.select_tuples(points, s, omegas, 40, rng=rng, rule="best_n", **SELECT)
    beam = sel.select_tuples(points, s, omegas, 40, rng=rng, rule="best_n", join_sensors=3, **SELECT)
    np.testing.assert_array_equal(beam.tuples, exact.tuples)
    np.testing.assert_array_equal(beam.errors, exact.errors)


@pytest.mark.parametrize("n_sensors", [4, 5, 6])
def test_the_beam_keeps_the_true_tuple_and_the_normal_check(n_sensors):
    rng = np.random.default_rng(n_sensors)
    points, normals, true, s, m = _normal_scene(rng, 400, n_sensors)
    check = sel.NormalCheck(normals, m, np.radians(20.0))
    omegas = [np.union1d(rng.choice(400, 120, replace=False), [t]) for t in true]
    result = sel.select_tuples(points, s, omegas, 200, rng=rng, rule="best_n", normals=check, join_sensors=3, **SELECT)
    assert any(np.array_equal(row, true) for row in result.tuples)  # exact contacts: error 0, kept by every step
    assert sel.tuples_normal_consistent(points, s, result.tuples, check).all()
    np.testing.assert_array_equal(result.errors, sel.tuples_to_errors(points, s, result.tuples))
    assert result.errors.max() < SELECT["delta_max"] and result.tuples.shape[0] == 200


def test_join_sensors_must_be_at_least_two():
    rng = np.random.default_rng(0)
    points, _true, s = _scene(rng, 30, 4)
    with pytest.raises(InputError, match="join_sensors"):
        sel.select_tuples(points, s, [np.arange(30)] * 4, 5, rng=rng, rule="best_n", join_sensors=1, **SELECT)
