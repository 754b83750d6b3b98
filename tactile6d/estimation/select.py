"""Selecting candidate L-tuples of database points, one point per sensor (docs/design.md, The method).

Tactile-based selection: sensor i keeps the database points whose latent angle is within
``delta_h`` of its image's angle, Omega_i = {j : |a_db[j] - a_obs[i]| < delta_h}.

Distance-based selection: a tuple (j_1, ..., j_L) in Omega_1 x ... x Omega_L is kept when the
mean over sensor pairs of ``| ||P[j_a] - P[j_b]|| - ||s_a - s_b|| |`` is below ``delta_d``. The product
is never materialised: every pair's error is at most the *sum* of the pair errors, which is below
``n_pairs * delta_d``, so the tuples are grown one sensor at a time from the rows of pair-error tables
filtered by that bound, carrying the running sum and dropping a partial tuple as soon as its sum
reaches the bound. The survivors' mean errors are then recomputed exactly as the brute force does,
so both return the same set (``test_selection.py`` checks it).

Adaptive ``delta_d`` (the paper, and the rule of its reference code): start at ``delta_start``; while
more than ``n_max`` tuples pass, lower it by ``step_down``; if nothing passes, raise it by ``step_up``
until something does. Because the count is monotone in ``delta_d``, the result depends only on the
sorted errors, so it is found by joining at small thresholds first (cheap) rather than by
enumerating at ``delta_start`` (8e9 triples for the baseline). When raising by ``step_up`` jumps from
0 to more than ``n_max`` tuples, the reference code keeps them all; here the ``n_max`` tuples with the
lowest mean error are kept (ties by index order), so memory and the optimiser's time stay bounded,
and ``DistanceSelection.capped`` says so.

Rule ``best_n`` (``select.delta_d_rule: best_n``, not the paper's): keep exactly the ``n_max`` tuples
of smallest mean error (ties by index order), whatever threshold that takes. The paper's rule
usually stops at a delta_d far below the spacing of the database points (docs/design.md, The
method and Beyond the paper), so the tuple of the points nearest the true contacts is rarely kept.
The threshold is found by doubling from ``step_up`` then bisecting, each probe a pruned join that
stops once it has seen more than 4 ``n_max`` tuples; the product is never materialised.

Sensor poses that are off (``sensors.pose_sigma_*``, ``settings.SensorSettings``): the sensors' pair
distances are then off too, by up to ``tolerance`` (m), so a threshold below it could drop the true
tuple for no better reason than the kinematics' noise. Under the adaptive rule the threshold is never
lowered below ``tolerance``: when it stops lower, the ``n_max`` lowest-error tuples below ``tolerance``
are kept instead (all of them when fewer). Rule ``best_n`` keeps its ``n_max`` lowest whatever the
tolerance, which is the same set: it only ever stops below the tolerance with exactly ``n_max``.
The normal check's tolerance widens by how far the sensors' turns move the pair angles
(``estimation.select``).

Normal consistency (``select.normal_tol_deg``, optional): each sensor's +x axis is the inward surface
normal at its contact, so the database normals of a plausible tuple must be carried onto the sensors'
contact normals by one rotation. A necessary condition checked per sensor pair (a, b) is that the
three angles of the pair's point-pair feature agree within the tolerance: angle(n_a, n_b),
angle(n_a, d_ab) and angle(n_b, d_ab), with d_ab the unit vector from a's point to b's, on the
database side (object frame) and on the sensors' side (world). Pairs that fail are marked in the
pair tables (pruned in the join), and every surviving tuple is checked again exactly in float64, as the
brute force does, so both still return the same set.

More sensors than ``join_sensors`` (``select.join_sensors``, rule ``best_n``): the pruned join's work grows
steeply with L, since each partial tuple may spend the whole budget of all L (L - 1) / 2 pairs on its first
ones (medians of 0.2-0.5 s a scene at L = 4 and about 3 s at L = 5, up to 36 s, against 0.03 s at L = 3:
docs/speed.md). Beyond ``join_sensors`` sensors, the ``n_max`` best tuples of the ``join_sensors`` sensors
with the fewest candidates are found as above (exactly), then the other sensors are added one at a time, in
order of their candidate counts: every kept partial tuple is extended by every candidate of the next
sensor, and the ``n_max`` extensions of lowest summed pair error are kept (a beam; ties by position). The
survivors' mean errors over all pairs are recomputed exactly, those below ``delta_max`` that pass the
normal check kept, the ``n_max`` lowest returned. Not the exact ``n_max`` lowest of all L-tuples: a beam
that starts from the tuples that fit a subset of the sensors best, as at L = 3; on the generated scenes of
docs/speed.md as accurate as the exact join within the spread between seeds. ``test_selection.py`` checks
it against a naive beam written with loops.

The baseline is the same with Omega_i = all M points: ``all_points_omegas``. Timings: docs/speed.md.

Units: metres for points and thresholds, radians for latent angles.

``select`` is step 2 of an estimate, as the estimator and the select stage call it: tactile selection keeps, per sensor, the database points whose latent angle is within ``delta_h`` of
the image's (``select.angles_to_omegas``); distance selection keeps the tuples of those points whose
pairwise distances match the sensors' (``select.select_tuples``). Nothing matching either is a
``NoMatch`` outcome, not an input error.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import cdist

from tactile6d.core.errors import InputError, NoMatch
from tactile6d.core.settings import DELTA_D_RULES, SelectSettings, SensorSettings
from tactile6d.perception.contacts import Contacts

# How many candidate extensions one vectorised step of the join handles (memory: ~50 bytes each).
_JOIN_CHUNK = 1 << 21
# How many (partial tuple, candidate) sums one step of the beam extension holds at once (float32: 16 MB).
_EXTEND_CHUNK = 1 << 22


@dataclass(frozen=True)
class TactileSelection:
    """omegas: L int64 arrays of database indices; delta_h: (L,) the threshold each sensor used (rad)."""

    omegas: tuple[np.ndarray, ...]
    delta_h: np.ndarray


@dataclass(frozen=True)
class DistanceSelection:
    """The kept tuples.

    tuples (T, L) int64 database indices, rows in lexicographic order; errors (T,) their mean pair
    distance error (m); delta_d the threshold the adaptive rule stopped at (m); capped: True when more
    than ``n_max`` tuples passed ``delta_d`` and only the ``n_max`` lowest-error ones were kept (rule
    best_n: when one of the thresholds it tried, all below delta_max, passed more than ``n_max``; it
    may miss that more exist when the last one passed exactly ``n_max``).
    """

    tuples: np.ndarray
    errors: np.ndarray
    delta_d: float
    capped: bool


@dataclass(frozen=True)
class NormalCheck:
    """Normal consistency (module docstring): normals (M, 3) the database points' outward unit normals
    (object frame), sensor_normals (L, 3) the sensors' contact normals (world, ``sensor.contact_normals``),
    tol the largest disagreement of a point-pair-feature angle (rad)."""

    normals: np.ndarray
    sensor_normals: np.ndarray
    tol: float


def pair_feature_angles(p_a, p_b, n_a, n_b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The angles (rad) of a point-pair feature, broadcast over (..., 3) inputs:
    angle(n_a, n_b), angle(n_a, d), angle(n_b, d) with d = (p_b - p_a) / ||p_b - p_a|| (NaN when the
    points coincide). Written element by element, like ``pair_distances``, so the same pair gives
    bit-identical angles whatever the array shapes."""
    p_a, p_b, n_a, n_b = (np.asarray(x, dtype=np.float64) for x in (p_a, p_b, n_a, n_b))
    length = pair_distances(p_a, p_b)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = [(p_b[..., c] - p_a[..., c]) / length for c in range(3)]

    def dot(u, v):
        out = u[0] * v[0]
        out = out + u[1] * v[1]
        out = out + u[2] * v[2]
        return np.arccos(np.clip(out, -1.0, 1.0))

    na = [n_a[..., c] for c in range(3)]
    nb = [n_b[..., c] for c in range(3)]
    return dot(na, nb), dot(na, d), dot(nb, d)


def _pair_consistent(p_a, p_b, n_a, n_b, s_a, s_b, m_a, m_b, tol: float) -> np.ndarray:
    """Database pair (p, n) against sensor pair (s, m): every feature angle within tol (bool, broadcast)."""
    ok = None
    for x, y in zip(pair_feature_angles(p_a, p_b, n_a, n_b), pair_feature_angles(s_a, s_b, m_a, m_b)):
        good = np.abs(x - y) <= tol  # NaN (coincident points) fails
        ok = good if ok is None else ok & good
    return ok


def tuples_normal_consistent(points: np.ndarray, sensor_points: np.ndarray, tuples: np.ndarray, check: NormalCheck) -> np.ndarray:
    """(T,) bool: every sensor pair of each tuple (T, L) passes the point-pair-feature test (module docstring)."""
    points = np.asarray(points, dtype=np.float64)
    s = np.asarray(sensor_points, dtype=np.float64)
    n, m = np.asarray(check.normals, dtype=np.float64), np.asarray(check.sensor_normals, dtype=np.float64)
    tuples = np.asarray(tuples)
    ok = np.ones(tuples.shape[0], dtype=bool)
    for a, b in _pairs(s.shape[0]):
        ja, jb = tuples[:, a], tuples[:, b]
        ok &= _pair_consistent(points[ja], points[jb], n[ja], n[jb], s[a], s[b], m[a], m[b], check.tol)
    return ok


def angles_to_omegas(
    a_db: np.ndarray, a_obs: np.ndarray, delta_h: float, widen_step: float, widen_max: float
) -> TactileSelection:
    """Tactile-based selection.

    a_db (M,) latent angles of the database images, a_obs (L,) those of the sensors' images (rad).
    Omega_i = {j : |a_db[j] - a_obs[i]| < delta_h}. A sensor whose Omega_i is empty gets its own
    threshold widened by ``widen_step`` until it is not (a warning says so), at most to ``widen_max``;
    beyond that NoMatch is raised, since the image then matches nothing in the database.
    """
    a_db = np.asarray(a_db, dtype=np.float64)
    a_obs = np.atleast_1d(np.asarray(a_obs, dtype=np.float64))
    if a_db.ndim != 1 or a_db.size == 0:
        raise InputError(f"database angles must be a non-empty 1-D array, got shape {a_db.shape}")
    if not (delta_h > 0 and widen_step > 0 and widen_max >= delta_h):
        raise InputError(f"need delta_h > 0, widen_step > 0, widen_max >= delta_h; got {delta_h}, {widen_step}, {widen_max}")
    gaps = np.abs(a_db[None, :] - a_obs[:, None])
    omegas, used = [], []
    for i, gap in enumerate(gaps):
        # Widening in integer steps from delta_h keeps the used threshold on the documented grid.
        n_steps = int(np.ceil(max(0.0, gap.min() - delta_h) / widen_step))
        threshold = delta_h + n_steps * widen_step
        if not np.any(gap < threshold):
            n_steps += 1
            threshold = delta_h + n_steps * widen_step
        if threshold > widen_max + 1e-12:
            raise NoMatch(
                f"sensor {i}: no database image within delta_h={widen_max:g} rad of its latent angle "
                f"(nearest is {gap.min():.4g} rad away); is it the right object?"
            )
        if n_steps:
            warnings.warn(
                f"sensor {i}: empty selection at delta_h={delta_h:g} rad, widened to {threshold:g}",
                stacklevel=2,
            )
        omegas.append(np.flatnonzero(gap < threshold))
        used.append(threshold)
    return TactileSelection(tuple(omegas), np.array(used))


def all_points_omegas(n_points: int, n_sensors: int) -> tuple[np.ndarray, ...]:
    """The baseline's selection: every database point for every sensor, L arrays arange(M)."""
    return tuple(np.arange(n_points) for _ in range(n_sensors))


def pair_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a (..., 3), b (..., 3) -> (...) broadcast: ||a - b||, written out one coordinate at a time.

    Element-wise arithmetic in a fixed order is bit-reproducible whatever the array shapes, unlike a
    reduction, so the pruned join and the brute force compute identical errors for the same tuple.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    out = a[..., 0] - b[..., 0]
    out *= out
    for c in (1, 2):
        d = a[..., c] - b[..., c]
        d *= d
        out += d
    return np.sqrt(out, out=out) if isinstance(out, np.ndarray) else np.sqrt(out)


def _pairs(n_sensors: int) -> list[tuple[int, int]]:
    return list(itertools.combinations(range(n_sensors), 2))


def _pair_errors(points: np.ndarray, s: np.ndarray, i_a: np.ndarray, i_b: np.ndarray, a: int, b: int) -> np.ndarray:
    """(T,) m: ``| ||P[i_a] - P[i_b]|| - ||s_a - s_b|| |``, database indices i_a, i_b (T,) of sensors a and b.

    The one place this arithmetic is written: the join's float64 decisions and ``tuples_to_errors`` must
    agree to the bit, or a tuple the join kept could be re-scored differently.
    """
    return np.abs(pair_distances(points[i_a], points[i_b]) - pair_distances(s[a], s[b]))


def tuples_to_errors(points: np.ndarray, sensor_points: np.ndarray, tuples: np.ndarray) -> np.ndarray:
    """Mean over sensor pairs of the distance mismatch.

    points (M, 3) database points (object frame, m), sensor_points (L, 3) sensor contact points (world,
    m), tuples (T, L) int -> (T,) metres. With L = 1 there is no pair and the error is 0.
    """
    points = np.asarray(points, dtype=np.float64)
    s = np.asarray(sensor_points, dtype=np.float64)
    tuples = np.asarray(tuples)
    pairs = _pairs(s.shape[0])
    total = np.zeros(tuples.shape[0])
    for a, b in pairs:
        total = total + _pair_errors(points, s, tuples[:, a], tuples[:, b], a, b)
    return total / max(len(pairs), 1)


def _check_inputs(points, sensor_points, omegas):
    points = np.asarray(points, dtype=np.float64)
    s = np.asarray(sensor_points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"database points must be (M, 3), got {points.shape}")
    if s.ndim != 2 or s.shape[1] != 3 or s.shape[0] < 1:
        raise InputError(f"sensor points must be (L, 3) with L >= 1, got {s.shape}")
    if len(omegas) != s.shape[0]:
        raise InputError(f"{len(omegas)} index sets for {s.shape[0]} sensors")
    omegas = tuple(np.unique(np.asarray(o, dtype=np.int64)) for o in omegas)
    for i, o in enumerate(omegas):
        if o.size == 0:
            raise InputError(f"sensor {i}: empty set of candidate database points")
        if o[0] < 0 or o[-1] >= points.shape[0]:
            raise InputError(f"sensor {i}: database index out of range 0..{points.shape[0] - 1}")
    return points, s, omegas


def _sorted_rows(tuples: np.ndarray, errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.lexsort(tuples.T[::-1]) if tuples.shape[0] else np.zeros(0, dtype=np.int64)
    return tuples[order], errors[order]


def tuples_within_brute_force(
    points: np.ndarray, sensor_points: np.ndarray, omegas, delta_d: float, normals: NormalCheck | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Reference for ``tuples_within``: enumerate Omega_1 x ... x Omega_L. Small inputs only.

    Returns tuples (T, L) int64 in lexicographic order with mean error < delta_d (and, with
    ``normals``, normal-consistent), and errors (T,) m.
    """
    points, s, omegas = _check_inputs(points, sensor_points, omegas)
    grids = np.meshgrid(*omegas, indexing="ij")
    tuples = np.stack([g.ravel() for g in grids], axis=1)
    errors = tuples_to_errors(points, s, tuples)
    keep = errors < delta_d
    if normals is not None:
        keep &= tuples_normal_consistent(points, s, tuples, normals)
    return _sorted_rows(tuples[keep], errors[keep])


def tuples_within(
    points: np.ndarray, sensor_points: np.ndarray, omegas, delta_d: float, normals: NormalCheck | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """All tuples of Omega_1 x ... x Omega_L with mean pair error < delta_d, by a pruned join.

    points (M, 3) m, sensor_points (L, 3) m, omegas: L index arrays, delta_d m, normals: the optional
    normal-consistency test -> tuples (T, L) int64 in lexicographic order, errors (T,) m. Same result
    as the brute force.
    """
    points, s, omegas = _check_inputs(points, sensor_points, omegas)
    tuples, errors, _ = _join(points, s, omegas, _PairTables(points, s, omegas, normals), delta_d)
    return _sorted_rows(tuples, errors)


class _PairTables:
    """The pair-error tables of one problem, shared by the joins at successive thresholds.

    ``table[(a, k)]`` (|Omega_a|, |Omega_k|) float32, for each pair a < k: the pair's distance error
    (m), from one distance matrix over the union of the omegas (the baseline's omegas coincide).
    These only prune; every kept tuple's error is recomputed exactly in float64. With a NormalCheck,
    entries of pairs that fail it (by more than a rounding slack) are +inf, so the join never grows them.
    """

    def __init__(self, points: np.ndarray, s: np.ndarray, omegas, normals: NormalCheck | None = None):
        union = np.unique(np.concatenate(omegas))
        dist = cdist(points[union], points[union])
        self.normals = normals
        self.table = {}
        for a, k in _pairs(s.shape[0]):
            rows, cols = np.searchsorted(union, omegas[a]), np.searchsorted(union, omegas[k])
            err = dist[np.ix_(rows, cols)]
            err -= pair_distances(s[a], s[k])
            table = np.abs(err, out=err).astype(np.float32)
            if normals is not None:
                n, m = np.asarray(normals.normals, dtype=np.float64), np.asarray(normals.sensor_normals, dtype=np.float64)
                ja, jk = omegas[a][:, None], omegas[k][None, :]
                ok = _pair_consistent(points[ja], points[jk], n[ja], n[jk], s[a], s[k], m[a], m[k],
                                      normals.tol + _ANGLE_SLACK)
                table[~ok] = np.inf
            self.table[(a, k)] = table

    def pair(self, a: int, b: int) -> np.ndarray:
        """The table of sensors a and b (a != b): (|Omega_a|, |Omega_b|) float32."""
        return self.table[(a, b)] if a < b else self.table[(b, a)].T

    def subset(self, sensors) -> _PairTables:
        """The tables of the sensors ``sensors`` (increasing indices) alone, renumbered 0, 1, ... in that
        order, with the normal check restricted to them: what ``_join`` needs to join those sensors."""
        view = object.__new__(_PairTables)
        view.table = {(i, j): self.table[(a, b)]
                      for (i, a), (j, b) in itertools.combinations(enumerate(int(x) for x in sensors), 2)}
        check = self.normals
        view.normals = None if check is None else NormalCheck(
            check.normals, np.asarray(check.sensor_normals)[np.asarray(sensors)], check.tol)
        return view

    def anchor(self, k: int, bound: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The entries of table (0, k) below ``bound``, sorted by (row, error).

        Returns keys = row + error / scale (so that a threshold per row is one global searchsorted),
        the column of each entry, the first entry of each row (|Omega_0| + 1,), and scale.
        """
        err = self.table[(0, k)]
        rows, cols = np.nonzero(err < bound)
        scale = 2.0 * bound + 1.0  # errors / scale lie in [0, 1): they never reach the next row's keys
        keys = rows + err[rows, cols] / scale
        order = np.argsort(keys, kind="stable")
        return keys[order], cols[order], np.searchsorted(rows, np.arange(err.shape[0] + 1)), scale


# float32 tables round each pair error by at most ~3e-8 m; pruning with this much slack (m) can
# therefore never drop a tuple that the exact float64 check keeps.
_TABLE_SLACK = 1e-6
# Tolerance slack (rad) of the tables' normal test: they only prune, the exact test decides.
_ANGLE_SLACK = 1e-9


def _join(points, s, omegas, tables: _PairTables, delta_d: float, stop_after: int | None = None,
          max_checks: int | None = None):
    """Tuples with mean pair error < delta_d: (tuples (T, L), errors (T,), complete), unsorted.

    Grows partial tuples one sensor at a time. A partial tuple's running sum of pair errors must stay
    below the budget ``n_pairs * delta_d`` (the remaining pairs only add to it), and the candidates for
    sensor k are read from row j_0 of the anchor table (0, k), sorted by error, only as far as the
    remaining budget allows. With ``stop_after``, it returns early (complete = False) once more than
    that many tuples have passed. With ``max_checks``, NoMatch once more than that many extensions of
    partial tuples have been checked (``select_tuples``).
    """
    n_sensors = s.shape[0]
    if n_sensors == 1:
        tuples = omegas[0][:, None]
        errors = np.zeros(tuples.shape[0])
        keep = errors < delta_d
        return tuples[keep], errors[keep], True
    check = tables.normals

    n_pairs = n_sensors * (n_sensors - 1) // 2
    budget = n_pairs * delta_d + _TABLE_SLACK
    partial = np.arange(omegas[0].size)[:, None]
    sums = np.zeros(omegas[0].size)
    found_tuples, found_errors, n_found, checks = [], [], 0, 0
    for k in range(1, n_sensors):
        keys, cols, starts, scale = tables.anchor(k, budget)
        last = k == n_sensors - 1
        rows = partial[:, 0]
        counts = np.searchsorted(keys, rows + (budget - sums) / scale) - starts[rows]
        np.maximum(counts, 0, out=counts)
        ends = np.cumsum(counts)
        grown_parts, grown_sums = [], []
        lo = 0
        while lo < partial.shape[0]:
            # The next run of partial tuples whose extensions fit in one vectorised step.
            hi = max(int(np.searchsorted(ends, ends[lo] - counts[lo] + _JOIN_CHUNK, side="right")), lo + 1)
            c = counts[lo:hi]
            checks += int(c.sum())
            if max_checks is not None and checks > max_checks:
                raise NoMatch(f"more than {max_checks:.3g} partial tuples to check at delta_d={delta_d:g} m: the "
                              "sensors' pairwise distances fit this object's database points nearly everywhere "
                              "pair by pair, but not (yet) all together (e.g. a sphere against a curved object)")
            owner = np.repeat(np.arange(lo, hi), c)
            new = cols[np.repeat(starts[rows[lo:hi]] - (np.cumsum(c) - c), c) + np.arange(owner.size)]
            total = sums[owner]
            for a in range(k):
                total = total + tables.table[(a, k)][partial[owner, a], new]
            keep = total < budget
            grown = np.concatenate([partial[owner[keep]], new[keep, None]], axis=1)
            lo = hi
            if not last:
                grown_parts.append(grown)
                grown_sums.append(total[keep])
                continue
            # Last sensor: the exact float64 check, the same arithmetic as the brute force.
            tuples = np.stack([omegas[i][grown[:, i]] for i in range(n_sensors)], axis=1)
            errors = tuples_to_errors(points, s, tuples)
            passed = errors < delta_d
            if check is not None:
                passed &= tuples_normal_consistent(points, s, tuples, check)
            found_tuples.append(tuples[passed])
            found_errors.append(errors[passed])
            n_found += int(passed.sum())
            if stop_after is not None and n_found > stop_after and lo < partial.shape[0]:
                return np.concatenate(found_tuples), np.concatenate(found_errors), False
        if not last:
            partial = np.concatenate(grown_parts) if grown_parts else np.zeros((0, k + 1), dtype=np.int64)
            sums = np.concatenate(grown_sums) if grown_sums else np.zeros(0)
    if not found_tuples:
        return np.zeros((0, n_sensors), dtype=np.int64), np.zeros(0), True
    return np.concatenate(found_tuples), np.concatenate(found_errors), True



def _lowest(tuples: np.ndarray, errors: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The n lowest errors, ties broken by index order, returned in lexicographic row order."""
    order = np.lexsort(tuple(tuples.T[::-1]) + (errors,))[:n]
    return _sorted_rows(tuples[order], errors[order])


def _growth(count: int, n_max: int, n_pairs: int) -> float:
    """How much to raise delta_d after a complete probe that found ``count`` < n_max tuples: towards where
    about 2 n_max pass, the count growing about as delta_d ** n_pairs (one slab of width ~delta_d per
    sensor pair), by 1.25 to 4 times; 3 times when it found none. Only a guess for the next probe, which
    saves probes (each a join): the result does not depend on it."""
    if count == 0:
        return 3.0
    return float(np.clip((2.0 * n_max / count) ** (1.0 / n_pairs), 1.25, 4.0))


def _best_n(join, n_max: int, delta_first: float, delta_max: float, n_pairs: int) -> DistanceSelection:
    """Rule best_n: the n_max tuples of lowest mean error (< delta_max), ties by index order.

    count(delta) = #tuples with error < delta grows with delta. Raising delta from ``delta_first``
    (``_growth``) finds an upper bracket with at least n_max tuples (or stops at delta_max). A probe
    stops early once it has seen more than 4 n_max tuples; the n_max-th lowest error among those it saw
    is an upper bound on the n_max-th lowest overall, so the next probe goes just above it, where at
    least n_max tuples pass. The bracket narrows until a probe completes; bisection takes over when the
    bound does not shrink (a pile of equal errors). For an object that fits the sensors badly, the first
    bracket holds far more than n_max tuples, and this takes one or two probes where bisection took
    several (timings: docs/speed.md).
    """
    cap = 4 * n_max
    lo, delta = 0.0, min(delta_first, delta_max)
    while True:
        tuples, errors, complete = join(delta, cap)
        seen = tuples.shape[0]  # the most tuples one probe found: more than n_max means capped
        if not complete or tuples.shape[0] >= n_max:
            hi = delta
            break
        if delta >= delta_max:
            if tuples.shape[0] == 0:
                raise NoMatch(
                    "no tuple of database points matches the sensors' pairwise distances within "
                    f"delta_d={delta_max:g} m"
                )
            tuples, errors = _sorted_rows(tuples, errors)
            return DistanceSelection(tuples, errors, float(errors.max()), False)
        lo, delta = delta, min(delta * _growth(tuples.shape[0], n_max, n_pairs), delta_max)
    while not complete:
        if hi - lo < 1e-10:  # a pathological pile of equal errors: take them all, then the lowest
            tuples, errors, complete = join(hi, None)
            seen = max(seen, tuples.shape[0])
            break
        # errors: more than n_max tuples, all below hi (the last early-stopped probe's).
        bound = float(np.nextafter(np.partition(errors, n_max - 1)[n_max - 1], np.inf))
        probe = bound if bound < hi else 0.5 * (lo + hi)
        t, e, c = join(probe, cap)
        if c and t.shape[0] < n_max:
            lo = probe
        else:
            hi, tuples, errors, complete = probe, t, e, c
            seen = max(seen, t.shape[0])
    tuples, errors = _lowest(tuples, errors, n_max)
    return DistanceSelection(tuples, errors, float(errors.max()), seen > n_max)


def _lowest_extensions(sums: np.ndarray, tables: _PairTables, positions: dict[int, np.ndarray], m: int, k: int
                       ) -> tuple[np.ndarray, int]:
    """The (partial tuple, candidate of sensor m) pairs that may be among the k of lowest summed pair error.

    sums (P,) the partial tuples' summed pair errors (m); positions: sensor -> (P,) each partial tuple's
    position in that sensor's Omega. Returns (flat indices p * |Omega_m| + j, increasing, of every pair whose
    float32 sum from the tables is within a rounding slack of the k-th lowest: a superset of the k lowest
    exact sums), and how many pairs have a finite sum (a pair the normal check rules out has none).
    """
    width = tables.pair(next(iter(positions)), m).shape[1]
    slack = 2 * (len(positions) + 1) * _TABLE_SLACK  # each float32 sum is within half of it of the exact one
    rows = max(1, _EXTEND_CHUNK // width)
    kept, finite = [], 0
    for lo in range(0, sums.size, rows):
        hi = min(lo + rows, sums.size)
        total = np.repeat(sums[lo:hi, None].astype(np.float32), width, axis=1)
        for a, pos in positions.items():
            total += tables.pair(a, m)[pos[lo:hi]]
        flat = total.ravel()
        n_finite = int(np.isfinite(flat).sum())
        finite += n_finite
        if n_finite == 0:
            continue
        # This chunk's k-th lowest is at least the overall k-th lowest: its slack band holds every pair of
        # the chunk that the overall band holds.
        kth = np.partition(flat, min(k, n_finite) - 1)[min(k, n_finite) - 1]
        kept.append(lo * width + np.flatnonzero(flat <= kth + slack))
    return (np.concatenate(kept) if kept else np.zeros(0, dtype=np.int64)), finite


def _best_n_extended(points: np.ndarray, s: np.ndarray, omegas, tables: _PairTables, n_max: int, delta_first: float,
                     delta_max: float, join_sensors: int, max_checks: int | None) -> DistanceSelection:
    """Rule best_n for more than ``join_sensors`` sensors (module docstring): the ``n_max`` best tuples of the
    ``join_sensors`` sensors with the fewest candidates, extended one sensor at a time keeping the ``n_max``
    of lowest summed pair error, then the ``n_max`` lowest mean errors below ``delta_max``."""
    by_size = [int(i) for i in np.argsort([o.size for o in omegas], kind="stable")]
    core = sorted(by_size[:join_sensors])
    n_core_pairs = join_sensors * (join_sensors - 1) // 2
    sub, core_omegas = tables.subset(core), tuple(omegas[i] for i in core)
    chosen = _best_n(lambda delta, stop_after=n_max: _join(points, s[core], core_omegas, sub, delta, stop_after, max_checks),
                     n_max, delta_first, delta_max, n_core_pairs)
    positions = {c: np.searchsorted(omegas[c], chosen.tuples[:, i]) for i, c in enumerate(core)}
    sums = np.zeros(chosen.tuples.shape[0])
    for a, b in itertools.combinations(core, 2):
        sums += _pair_errors(points, s, omegas[a][positions[a]], omegas[b][positions[b]], a, b)
    capped = chosen.capped
    for m in by_size[join_sensors:]:
        candidates, finite = _lowest_extensions(sums, tables, positions, m, n_max)
        if finite == 0:
            raise NoMatch(f"no candidate of sensor {m} passes the normal check with any tuple of the others")
        p, j = np.divmod(candidates, omegas[m].size)
        exact = sums[p].copy()
        for a, pos in positions.items():
            exact += _pair_errors(points, s, omegas[a][pos[p]], omegas[m][j], a, m)
        best = np.lexsort((candidates, exact))[:n_max]  # the lowest exact sums, ties by position
        capped = capped or finite > best.size
        positions = {a: pos[p[best]] for a, pos in positions.items()}
        positions[m], sums = j[best], exact[best]
    tuples = np.stack([omegas[i][positions[i]] for i in range(s.shape[0])], axis=1)
    errors = tuples_to_errors(points, s, tuples)
    keep = errors < delta_max
    if tables.normals is not None:
        keep &= tuples_normal_consistent(points, s, tuples, tables.normals)
    if not keep.any():
        raise NoMatch("no tuple of database points matches the sensors' pairwise distances within "
                      f"delta_d={delta_max:g} m")
    tuples, errors = _lowest(tuples[keep], errors[keep], n_max)
    return DistanceSelection(tuples, errors, float(errors.max()), capped)


def select_tuples(
    points: np.ndarray,
    sensor_points: np.ndarray,
    omegas,
    n_max: int,
    delta_start: float,
    step_down: float,
    step_up: float,
    delta_max: float,
    rng: np.random.Generator,
    rule: str = "paper",
    normals: NormalCheck | None = None,
    tolerance: float = 0.0,
    max_checks: int | None = None,
    join_sensors: int | None = None,
) -> DistanceSelection:
    """Distance-based selection with the adaptive threshold (module docstring).

    points (M, 3) database points in the object frame (m); sensor_points (L, 3) sensor contact points in
    the world (m); omegas: L index arrays (``angles_to_omegas(...).omegas`` or ``all_points_omegas``);
    n_max: the most tuples kept (N); delta_start, step_down, step_up, delta_max in metres; rng: used only
    for L = 1, where every point of Omega_1 is a tuple (error 0) and, if there are more than n_max, a
    uniformly random n_max of them are kept. rule: 'paper' (the adaptive delta_d) or 'best_n' (the
    n_max tuples of lowest error below delta_max; delta_d is then the largest kept error); normals:
    the optional normal-consistency test (``NormalCheck``; a test of pairs, so unused for L = 1);
    tolerance: m, how far the sensors' pair distances may be off (their poses' error,
    ``SensorSettings.pair_distance_tolerance``): the adaptive threshold is never lowered below it.
    max_checks: the most extensions of partial tuples one threshold's join may check (None: no limit).
    join_sensors: rule best_n with more sensors than this: the beam extension of the module docstring
    (None: every sensor joined exactly).
    The join's work grows with how many point pairs fit each sensor pair alone: for a sphere against
    three sensors on a larger curved object every pair fits somewhere and no triple does: its joins
    checked 7e9 extensions in 214 s to find none. The identification's screen sets it
    (``identify.screen.max_checks``), so that such an object costs seconds and is screened out.

    Raises NoMatch when no tuple passes even at ``delta_max`` (sensors farther apart, or closer,
    than any pair of database points allows), or when a join checks more than ``max_checks``.
    """
    points, s, omegas = _check_inputs(points, sensor_points, omegas)
    if n_max < 1 or not (delta_start > 0 and step_down > 0 and step_up > 0 and delta_max >= delta_start):
        raise InputError("need n_max >= 1, positive steps and delta_max >= delta_start > 0")
    if join_sensors is not None and not join_sensors >= 2:
        raise InputError(f"join_sensors must be None (join every sensor) or >= 2, got {join_sensors}")
    if not tolerance >= 0:
        raise InputError(f"the pair-distance tolerance must be >= 0 m, got {tolerance}")
    if rule not in DELTA_D_RULES:
        raise InputError(f"unknown delta_d rule {rule!r} ({' or '.join(DELTA_D_RULES)})")
    if s.shape[0] == 1:
        chosen = omegas[0]
        capped = chosen.size > n_max
        if capped:
            chosen = np.sort(rng.choice(chosen, size=n_max, replace=False))
        return DistanceSelection(chosen[:, None], np.zeros(chosen.size), float(delta_start), capped)

    tables = _PairTables(points, s, omegas, normals)

    def join(delta, stop_after=n_max):
        return _join(points, s, omegas, tables, delta, stop_after, max_checks)

    if rule == "best_n":
        if join_sensors is not None and s.shape[0] > join_sensors:
            return _best_n_extended(points, s, omegas, tables, n_max, step_up, delta_max, join_sensors, max_checks)
        return _best_n(join, n_max, step_up, delta_max, s.shape[0] * (s.shape[0] - 1) // 2)

    # The descending grid delta_start - k * step_down, down to its first non-positive value. The
    # reference stops at the first value with at most n_max tuples, which (the count growing with
    # delta) is the largest such value: scanning from the small end finds it with cheap joins that
    # stop as soon as n_max is exceeded. Values are rounded to the picometre to stay on the grid.
    n_down = int(np.ceil(delta_start / step_down - 1e-9))
    grid = [round(delta_start - k * step_down, 12) for k in range(n_down + 1)]
    delta, found = grid[-1], None
    for g in reversed(grid):
        if g <= 0:
            continue  # nothing is strictly below a non-positive threshold
        tuples, errors, complete = join(g)
        if not complete or tuples.shape[0] > n_max:
            break
        delta, found = g, (tuples, errors)

    if found is None or found[0].shape[0] == 0:
        # Raise by step_up until something passes.
        m = 1
        while True:
            delta_up = round(delta + m * step_up, 12)
            if delta_up > delta_max:
                raise NoMatch(
                    "no tuple of database points matches the sensors' pairwise distances within "
                    f"delta_d={delta_max:g} m"
                )
            if delta_up > 0:
                tuples, errors, complete = join(delta_up)
                if tuples.shape[0]:
                    if not complete:
                        tuples, errors, _ = join(delta_up, None)
                    delta, found = delta_up, (tuples, errors)
                    break
            m += 1

    if delta < tolerance:
        # Stopped below what the sensor poses' error can explain: the n_max lowest below the tolerance (a
        # superset of what was found, all of whose errors are below delta).
        return _best_n(join, n_max, step_up, min(tolerance, delta_max), s.shape[0] * (s.shape[0] - 1) // 2)
    tuples, errors = found
    capped = tuples.shape[0] > n_max
    # The n_max lowest errors (all of them when not capped), ties broken by index order.
    tuples, errors = _lowest(tuples, errors, n_max)
    return DistanceSelection(tuples, errors, float(delta), capped)


@dataclass(frozen=True)
class Selection:
    """Result and diagnostics of the selection step.

    tuples (T, L) int64 database indices, -1 for a sensor that does not touch (``Contacts.touching``);
    errors (T,) mean pair-distance error (m); omega_sizes (L,)
    |Omega_i|; delta_h (L,) the latent-angle threshold each sensor used (rad; NaN for the baseline);
    widened (L,) whether it had to be raised above ``delta_h``; delta_d the distance threshold
    the adaptive rule stopped at (m); capped: only the N lowest-error tuples were kept.
    """

    tuples: np.ndarray
    errors: np.ndarray
    omega_sizes: np.ndarray
    delta_h: np.ndarray
    widened: np.ndarray
    delta_d: float
    capped: bool

    def to_sensors(self, on: np.ndarray, n_sensors: int) -> Selection:
        """This selection, made for the sensors ``on`` (K,) int alone, given for all ``n_sensors``: a sensor
        left out has -1 in every tuple, an empty Omega_i, no delta_h (NaN) and no widening."""
        tuples = np.full((self.tuples.shape[0], n_sensors), -1, dtype=self.tuples.dtype)
        tuples[:, on] = self.tuples
        omega_sizes = np.zeros(n_sensors, dtype=self.omega_sizes.dtype)
        omega_sizes[on] = self.omega_sizes
        delta_h = np.full(n_sensors, np.nan)
        delta_h[on] = self.delta_h
        widened = np.zeros(n_sensors, dtype=bool)
        widened[on] = self.widened
        return Selection(tuples, self.errors, omega_sizes, delta_h, widened, self.delta_d, self.capped)


def select(
    points: np.ndarray,
    db_angles: np.ndarray | None,
    contacts: Contacts,
    angles: np.ndarray | None,
    settings: SelectSettings,
    normals: np.ndarray | None = None,
    *,
    sensors: SensorSettings,
) -> Selection:
    """Tactile then distance selection; method 'baseline' skips the tactile part (all M points per sensor).

    points (M, 3) database points (object frame, m); db_angles (M,) their latent angles (rad; unused
    by the baseline); contacts: the L sensors' contact points and normals (``tactile6d.perception.contacts``); angles (L,) the sensors' latent angles (rad; unused by
    the baseline); normals (M, 3) the points' outward normals, needed when ``normal_tol_deg``
    is set (normal-consistent tuples only); sensors: how far the sensor poses may be off, which widens
    the distance and normal tolerances (``SensorSettings.pair_distance_tolerance``, ``pair_angle_tolerance``).

    Only the sensors the object touches (``contacts.touching``: where some images show contact, those) are
    selected for; the others' columns of the tuples are -1 (``Selection.to_sensors``).
    """
    n_sensors = contacts.points.shape[0]
    on = np.flatnonzero(contacts.touching)
    if len(on) < n_sensors:
        part = select(points, db_angles, contacts.of_sensors(on), None if angles is None else np.asarray(angles)[on],
                      settings, normals, sensors=sensors)
        return part.to_sensors(on, n_sensors)
    check = None
    if settings.normals_apply(n_sensors):
        if normals is None:
            raise InputError("normal_tol_deg is set: the database normals are needed")
        check = NormalCheck(np.asarray(normals, dtype=np.float64), contacts.normals,
                                      float(np.radians(settings.normal_tol_deg)) + sensors.pair_angle_tolerance)
    if settings.method == "ours":
        if db_angles is None or angles is None:
            raise InputError("method 'ours' needs the database's and the images' latent angles")
        # The widening is reported in Selection.widened; no warning per scene.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tactile = angles_to_omegas(
                db_angles, angles, settings.delta_h, settings.delta_h_widen_step, settings.delta_h_max
            )
        omegas, delta_h = tactile.omegas, tactile.delta_h
        widened = delta_h > settings.delta_h + 1e-12
    else:
        omegas = all_points_omegas(points.shape[0], n_sensors)
        delta_h = np.full(n_sensors, np.nan)
        widened = np.zeros(n_sensors, dtype=bool)
    chosen = select_tuples(
        points,
        contacts.points,
        omegas,
        n_max=int(settings.N),
        delta_start=float(settings.delta_d_start),
        step_down=float(settings.delta_d_down),
        step_up=float(settings.delta_d_up),
        delta_max=float(settings.delta_d_max),
        rng=np.random.default_rng(settings.seed),
        rule=str(settings.delta_d_rule),
        normals=check,
        tolerance=sensors.pair_distance_tolerance,
        max_checks=None if settings.max_checks is None else int(settings.max_checks),
        join_sensors=None if settings.join_sensors is None else int(settings.join_sensors),
    )
    return Selection(
        tuples=chosen.tuples,
        errors=chosen.errors,
        omega_sizes=np.array([len(o) for o in omegas]),
        delta_h=np.asarray(delta_h, dtype=np.float64),
        widened=np.asarray(widened, dtype=bool),
        delta_d=chosen.delta_d,
        capped=chosen.capped,
    )
