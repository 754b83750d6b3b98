import warnings

import numpy as np
import pytest

from tactile6d import geometry as g
from tactile6d import selection as sel
from tactile6d.errors import InputError

SELECT = dict(delta_start=5e-3, step_down=5e-4, step_up=1e-4, delta_max=5e-2)


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
    points, true, s = _scene(rng, 60, n_sensors, noise=0.002)
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
    points, true, s = _scene(rng, 80, 3)
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
    points, true, s = _scene(rng, 120, 3, noise=0.001)
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


def test_raising_past_n_max_keeps_the_lowest_errors_ties_by_index():
    # Every point twice: tuples come in groups of equal error, so the count jumps from 0 past n_max = 3.
    rng = np.random.default_rng(3)
    points, true, s = _scene(rng, 40, 3, noise=0.001)
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


def test_impossible_distances_raise_input_error():
    rng = np.random.default_rng(0)
    points = _box_surface_points(30, rng)
    s = np.array([[0.0, 0, 0], [5.0, 0, 0]])  # 5 m apart: no pair of points on a 16 cm box
    with pytest.raises(InputError, match="no tuple"):
        sel.select_tuples(points, s, [np.arange(30)] * 2, 10, rng=rng, **SELECT)


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
        with pytest.raises(InputError, match="sensor 1"):
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
