"""Collision-aware ranking of pose hypotheses (docs/design.md, The method).

Score ``R_j = E_j + max_i d_ij``: the optimiser's loss plus the deepest penetration of the object at
pose j into any sensor's body. Near-duplicate poses (translations within ``tol_translation`` and
rotations within ``tol_rotation`` of a better-scored pose) are collapsed, then the ``top_k`` lowest
scores are returned, best first.

Only the poses that can still enter the top k are scored (branch and bound). Each pose carries a
lower bound on its score, at first its loss (depths are >= 0). A batch of the poses with the lowest
bounds is taken at a time: a pose whose bound came from the loss gets the first (cheapest) depth
bound function applied, one with the first bound gets the second, and so on; one with all bounds
gets its exact depths. This stops as soon as no unscored pose's bound is below the k-th best distinct
score so far: no unscored pose can then beat it, nor (coming later in score order) hide one of the top
k as its duplicate. The result is the same as scoring every pose (``rank_poses_brute_force``, checked
in the tests), provided every bound is a true lower bound. A pose's depths are the depth function's,
raised to the bounds already computed for it (so the function may leave the bounds out, as
``collision.poses_to_fcl_depths`` does). Ties in score are broken by input position.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from tactile6d.errors import InputError
from tactile6d.geometry import rotation_angle


@dataclass(frozen=True)
class RankedPoses:
    """The top k distinct poses, best first.

    poses (K, 4, 4) ``T_world_object``; scores (K,) m; losses (K,) m; penetrations (K, L) m;
    index (K,) positions in the ranked input; n_scored how many poses had their depths computed.
    """

    poses: np.ndarray
    scores: np.ndarray
    losses: np.ndarray
    penetrations: np.ndarray
    index: np.ndarray
    n_scored: int


def distinct_in_order(poses: np.ndarray, order: np.ndarray, tol_translation: float, tol_rotation: float, limit: int) -> list[int]:
    """Greedy de-duplication: walk ``order`` (indices into poses (P, 4, 4)) and keep a pose unless it
    is within tol_translation (m) and tol_rotation (rad) of one already kept; stop at ``limit`` kept.
    Returns the kept indices, in walking order.

    Vectorised over the walk: each pose kept strikes out at once every later pose that duplicates it, so
    the cost is one array operation per kept pose, not one per pose walked (the optimiser's hypotheses
    come in tight clusters, so most poses walked are duplicates). Same decisions, bit for bit, as the
    pose-by-pose walk (``tests/test_collision.py``'s reference).
    """
    order = np.asarray(order, dtype=np.int64).reshape(-1)
    translations = poses[order, :3, 3]
    rotations = poses[order, :3, :3]
    free = np.ones(len(order), dtype=bool)  # not a duplicate of a pose kept so far
    kept: list[int] = []
    start = 0
    while len(kept) < limit:
        ahead = np.flatnonzero(free[start:])
        if ahead.size == 0:
            break
        at = start + int(ahead[0])
        kept.append(int(order[at]))
        start = at + 1
        later = start + ahead[1:] - ahead[0] - 1  # the free positions after this one
        near_t = later[np.linalg.norm(translations[at] - translations[later], axis=1) <= tol_translation]
        if near_t.size:
            free[near_t[rotation_angle(rotations[at], rotations[near_t]) <= tol_rotation]] = False
    return kept


def penetration_cost(depths: np.ndarray, allowance: float = 0.0) -> np.ndarray:
    """(P, L) penetration depths (m) -> (P,) what a pose's score pays for them: the deepest, less
    ``allowance`` (the sensor poses' expected error: a true pose seen through sensor poses off by a
    millimetre penetrates a sensor by about that much), never below 0."""
    return np.maximum(np.asarray(depths).max(axis=1) - allowance, 0.0)


def rank_poses(
    poses: np.ndarray,
    losses: np.ndarray,
    penetrations: Callable[[np.ndarray], np.ndarray],
    top_k: int,
    tol_translation: float,
    tol_rotation: float,
    depth_bounds: Sequence[Callable[[np.ndarray], np.ndarray]] = (),
    batch: int = 256,
    allowance: float = 0.0,
) -> RankedPoses:
    """The top_k distinct poses by R = E + max(max_i d_i - allowance, 0), scoring only the poses that can
    make it.

    poses (P, 4, 4), losses (P,) m, penetrations: a function (B, 4, 4) -> (B, L) depths in metres
    (e.g. ``functools.partial(collision.poses_to_fcl_depths, model, T_world_sensor=...)``), which are
    raised to the pose's bounds; top_k, tol_translation m, tol_rotation rad, depth_bounds: functions
    (B, 4, 4) -> (B, L) lower bounds on the depths, cheapest first; batch: poses handled per step;
    allowance: m of penetration that costs nothing (``penetration_cost``). The depths returned are the
    penetrations themselves.
    """
    poses = np.asarray(poses, dtype=np.float64)
    losses = np.asarray(losses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or losses.shape != poses.shape[:1] or poses.shape[0] == 0:
        raise InputError(f"need poses (P, 4, 4) and losses (P,) with P >= 1, got {poses.shape}, {losses.shape}")
    if top_k < 1:
        raise InputError(f"top_k must be >= 1, got {top_k}")
    n_levels = len(depth_bounds)
    key = losses.copy()  # lower bound on each pose's score
    level = np.zeros(len(losses), dtype=np.int64)  # bounds applied so far; n_levels + 1 = scored
    lower = None  # (P, L) the largest depth bound computed so far for each pose and sensor
    scored = np.zeros(0, dtype=np.int64)
    depth_rows, scores = [], np.zeros(0)
    kept: list[int] = []
    while True:
        threshold = scores[kept[-1]] if len(kept) == top_k else np.inf
        open_ = np.flatnonzero((level <= n_levels) & (key < threshold))
        if open_.size == 0:
            break
        if open_.size > batch:
            # The batch lowest bounds, ties by input position.
            open_ = open_[np.lexsort((open_, key[open_]))[:batch]]
        # Each pose in the batch moves one step: to its next bound, or (all bounds known) to its depths.
        at = level[open_]
        for lvl in range(n_levels):
            chunk = open_[at == lvl]
            if chunk.size:
                bound = np.asarray(depth_bounds[lvl](poses[chunk]), dtype=np.float64)
                if lower is None:
                    lower = np.zeros((len(poses), bound.shape[1]))
                lower[chunk] = np.maximum(lower[chunk], bound)
                key[chunk] = np.maximum(key[chunk], losses[chunk] + penetration_cost(bound, allowance))
                level[chunk] = lvl + 1
        chunk = open_[at == n_levels]
        if chunk.size:
            depths = np.asarray(penetrations(poses[chunk]), dtype=np.float64)
            if lower is not None:
                depths = np.maximum(depths, lower[chunk])
            level[chunk] = n_levels + 1
            depth_rows.append(depths)
            scored = np.concatenate([scored, chunk])
            scores = np.concatenate([scores, losses[chunk] + penetration_cost(depths, allowance)])
            # Positions into `scored`, best score first, ties by input position.
            kept = distinct_in_order(poses[scored], np.lexsort((scored, scores)), tol_translation, tol_rotation, top_k)
    depths = np.concatenate(depth_rows)
    return RankedPoses(
        poses=poses[scored[kept]],
        scores=scores[kept],
        losses=losses[scored[kept]],
        penetrations=depths[kept],
        index=scored[kept],
        n_scored=len(scored),
    )


def rank_poses_brute_force(
    poses: np.ndarray,
    losses: np.ndarray,
    penetrations: Callable[[np.ndarray], np.ndarray],
    top_k: int,
    tol_translation: float,
    tol_rotation: float,
    allowance: float = 0.0,
) -> RankedPoses:
    """Reference for ``rank_poses``: score every pose, then de-duplicate and take the top k."""
    poses = np.asarray(poses, dtype=np.float64)
    losses = np.asarray(losses, dtype=np.float64)
    depths = np.asarray(penetrations(poses), dtype=np.float64)
    scores = losses + penetration_cost(depths, allowance)
    kept = distinct_in_order(poses, np.lexsort((np.arange(len(scores)), scores)), tol_translation, tol_rotation, top_k)
    return RankedPoses(poses[kept], scores[kept], losses[kept], depths[kept], np.asarray(kept, dtype=np.int64), len(poses))
