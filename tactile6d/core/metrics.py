"""Pose-error metrics: positional error, ADI (ADD-S), ADI-AUC, and top-k summaries (docs/design.md, The metrics).

Every distance is in metres; the evaluation converts to centimetres for display. A pose is a 4x4
``T_world_object``; batches of estimates have shape (..., 4, 4) and are compared with one true pose.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactile6d.core.geometry import invert_pose, transform_points

ADI_AUC_THRESHOLD = 0.02  # metres: an ADI above this counts as a failure
VOCAP_MAX_DISTANCE = 0.1  # metres: the YCB-Video accuracy curve is integrated from 0 to here
AUC_VARIANTS = ("paper", "standard")

# Model points transformed per cKDTree query batch: bounds the memory of a batched ADI at ~100 MB.
_POINTS_PER_QUERY = 1 << 22


def positional_error(T_est: np.ndarray, T_gt: np.ndarray) -> np.ndarray:
    """``||t_est - t_gt||``: T_est (..., 4, 4), T_gt (4, 4) or broadcastable -> (...) metres."""
    T_est = np.asarray(T_est, dtype=np.float64)
    T_gt = np.asarray(T_gt, dtype=np.float64)
    return np.linalg.norm(T_est[..., :3, 3] - T_gt[..., :3, 3], axis=-1)


def model_tree(model_points: np.ndarray) -> cKDTree:
    """A cKDTree over the model points (N, 3) in the object frame, reusable by every ADI call."""
    return cKDTree(np.asarray(model_points, dtype=np.float64))


def adi(
    model_points: np.ndarray, T_est: np.ndarray, T_gt: np.ndarray, tree: cKDTree | None = None
) -> np.ndarray:
    """ADI (ADD-S), metres: model_points (N, 3) object frame, T_est (..., 4, 4), T_gt (4, 4) -> (...).

    Definition: ``mean_i min_j || T_gt x_i - T_est x_j ||`` over the model points x, i.e. the mean
    distance from each model point **at the true pose** to the nearest model point at the estimated
    pose. This is Hinterstoisser et al.'s ADI (ACCV 2012), the BOP toolkit's ``adi`` and the paper's
    own evaluation code (``optimization/bop_pose_error.py`` of hsp-iit/multi-tactile-6d-estimation).
    The other direction (over the points at the estimate) is not the same number when the point set
    is uneven (docs/design.md, The metrics). It is 0 for any pose that maps the point set onto itself,
    so symmetric objects are not penalised.

    Computed in the object frame, ``min_j || T_est^-1 T_gt x_i - x_j ||`` (rigid motions keep
    distances), so one tree over the model points (``model_tree``; built here if not given) serves
    every estimate and every scene of the object.
    """
    points = np.asarray(model_points, dtype=np.float64)
    T_est = np.asarray(T_est, dtype=np.float64)
    tree = model_tree(points) if tree is None else tree
    T_rel = (invert_pose(T_est) @ np.asarray(T_gt, dtype=np.float64)).reshape(-1, 4, 4)
    out = np.empty(len(T_rel))
    chunk = max(1, _POINTS_PER_QUERY // max(1, len(points)))
    for start in range(0, len(T_rel), chunk):
        moved = transform_points(T_rel[start : start + chunk], points)
        distances, _ = tree.query(moved.reshape(-1, 3))
        out[start : start + chunk] = distances.reshape(len(moved), -1).mean(axis=1)
    return out.reshape(T_est.shape[:-2])


def with_true_translation(T_est: np.ndarray, T_gt: np.ndarray) -> np.ndarray:
    """(..., 4, 4): the estimated rotations with the translation of T_gt (4, 4)."""
    T = np.array(T_est, dtype=np.float64, copy=True)
    T[..., :3, 3] = np.asarray(T_gt, dtype=np.float64)[:3, 3]
    return T


def adi_rotation_only(
    model_points: np.ndarray, T_est: np.ndarray, T_gt: np.ndarray, tree: cKDTree | None = None
) -> np.ndarray:
    """Rotation-only ADI, metres, shapes as ``adi``: the ADI of the estimate whose translation is
    replaced by the true one, so only the rotation error (modulo symmetries) counts."""
    return adi(model_points, with_true_translation(T_est, T_gt), T_gt, tree)


def _checked_distances(distances: np.ndarray) -> np.ndarray:
    d = np.asarray(distances, dtype=np.float64).ravel()
    if d.size == 0:
        raise ValueError("ADI-AUC of an empty set of distances")
    if np.any(np.isnan(d)) or np.any(d < 0):
        raise ValueError("ADI distances must be non-negative numbers")
    return d


def auc_vocap(
    distances: np.ndarray, threshold: float = ADI_AUC_THRESHOLD, max_distance: float = VOCAP_MAX_DISTANCE
) -> float:
    """The paper's ADI-AUC, computed directly as YCB-Video's VOCap does: (n,) metres -> [0, 1].

    Distances above ``threshold`` become failures (infinite). The n distances are sorted; the
    accuracy reached at the k-th finite one is k/n. The curve is integrated from 0 to
    ``max_distance`` as a sum of rectangles, each interval between consecutive sorted distances
    taking the accuracy reached at its right end, the last interval (largest finite distance to
    ``max_distance``) the final accuracy m/n, and the area is divided by ``max_distance``.
    (The right-end rule credits each scene from the previous distance on, a little more than the
    exact area of the step curve ``fraction of d <= x``.)
    """
    if not 0 < threshold <= max_distance:
        raise ValueError("need 0 < threshold <= max_distance")
    d = np.sort(_checked_distances(distances))
    accuracy = np.arange(1, d.size + 1) / d.size
    finite = d <= threshold
    if not np.any(finite):
        return 0.0
    x = np.concatenate([[0.0], d[finite], [max_distance]])
    y = np.concatenate([accuracy[finite], accuracy[finite][-1:]])
    return float(np.sum(np.diff(x) * y) / max_distance)


def auc_vocap_closed_form(
    distances: np.ndarray, threshold: float = ADI_AUC_THRESHOLD, max_distance: float = VOCAP_MAX_DISTANCE
) -> float:
    """``auc_vocap`` in closed form: (n,) metres -> ``(m - sum_{k<m} d_(k) / max_distance) / n``.

    With d_(1) <= ... <= d_(m) the m distances within ``threshold`` and d_(0) = 0, the VOCap area is
    ``sum_{k=1..m} (d_(k) - d_(k-1)) k/n + (D - d_(m)) m/n`` with D = max_distance. Summing by parts,
    ``sum_k k (d_(k) - d_(k-1)) = m d_(m) - sum_{k<m} d_(k)``, so the area is
    ``(m D - sum_{k<m} d_(k)) / n``; divided by D = 0.1 this is
    ``(m - 10 * sum of the finite d except the largest) / n``.
    """
    if not 0 < threshold <= max_distance:
        raise ValueError("need 0 < threshold <= max_distance")
    d = _checked_distances(distances)
    finite = np.sort(d[d <= threshold])
    if finite.size == 0:
        return 0.0
    return float((finite.size - np.sum(finite[:-1]) / max_distance) / d.size)


def auc_standard(distances: np.ndarray, threshold: float = ADI_AUC_THRESHOLD) -> float:
    """The exact area under the accuracy curve up to ``threshold``, normalised: (n,) metres -> [0, 1].

    Equals ``mean(max(0, 1 - d / threshold))``: a perfect estimate scores 1, one at or beyond the
    threshold 0, linearly in between.
    """
    d = _checked_distances(distances)
    return float(np.mean(np.clip(1.0 - d / threshold, 0.0, None)))


def adi_auc(distances: np.ndarray, variant: str = "paper", threshold: float = ADI_AUC_THRESHOLD) -> float:
    """ADI-AUC of a set of ADI values (n,) metres, as a fraction in [0, 1].

    ``variant``: ``"paper"`` = ``auc_vocap`` (what produced the paper's table), ``"standard"`` =
    ``auc_standard``. The paper pools per object: #1 uses the best pose of each scene, #1-5 the ADIs
    of the five best poses of every scene together.
    """
    if variant == "paper":
        return auc_vocap(distances, threshold)
    if variant == "standard":
        return auc_standard(distances, threshold)
    raise ValueError(f"unknown ADI-AUC variant {variant!r}; expected one of {AUC_VARIANTS}")


def best(values: np.ndarray) -> np.ndarray:
    """#1: the metric of the best-ranked pose. values (..., K) in rank order -> (...)."""
    return np.asarray(values, dtype=np.float64)[..., 0]


def mean_top_k(values: np.ndarray, k: int = 5) -> np.ndarray:
    """#1-k: the mean metric over the k best-ranked poses (fewer if K < k). values (..., K) -> (...)."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape[-1] == 0 or k < 1:
        raise ValueError("mean_top_k needs at least one pose and k >= 1")
    return values[..., :k].mean(axis=-1)


def ranked_pose_errors(
    model_points: np.ndarray, T_ranked: np.ndarray, T_gt: np.ndarray, k: int = 5, tree: cKDTree | None = None
) -> dict[str, np.ndarray]:
    """The per-scene metrics of the k best poses: T_ranked (K, 4, 4), best first -> dict of (min(K, k),).

    Keys ``position`` (m), ``adi`` (m), ``adi_rotation`` (m); ``best`` and ``mean_top_k`` summarise
    them as #1 and #1-k, and the ADI arrays are what ``adi_auc`` pools over scenes.
    """
    T_top = np.asarray(T_ranked, dtype=np.float64)[:k]
    tree = model_tree(model_points) if tree is None else tree
    return {
        "position": positional_error(T_top, T_gt),
        "adi": adi(model_points, T_top, T_gt, tree),
        "adi_rotation": adi_rotation_only(model_points, T_top, T_gt, tree),
    }


def auroc(positive: np.ndarray, negative: np.ndarray) -> float:
    """Area under the ROC curve of a score that should be larger for ``positive`` than ``negative``.

    Equals the probability that a random positive scores above a random negative, ties counting one
    half (the Mann-Whitney U statistic over n_pos * n_neg). 0.5 is chance, 1 perfect separation.
    """
    pos = np.asarray(positive, dtype=np.float64).ravel()
    neg = np.asarray(negative, dtype=np.float64).ravel()
    if pos.size == 0 or neg.size == 0:
        return float("nan")
    from scipy.stats import rankdata

    ranks = rankdata(np.concatenate([pos, neg]))
    u = ranks[: pos.size].sum() - pos.size * (pos.size + 1) / 2.0
    return float(u / (pos.size * neg.size))


def auroc_within_groups(
    positive: np.ndarray, negative: np.ndarray, positive_groups: np.ndarray, negative_groups: np.ndarray
) -> float:
    """AUROC over the (positive, negative) pairs that share a group only: the probability that a random
    positive scores above a random negative of the same group, ties counting one half.

    Equals the per-group AUROCs averaged with weights n_pos * n_neg; groups lacking either side add no
    pairs; NaN when no group has both. Used per object for the latent angle, which is only ever compared
    within one object's database, so an offset between objects' angles does not count against it.
    """
    pos, neg = np.asarray(positive).ravel(), np.asarray(negative).ravel()
    pos_groups, neg_groups = np.asarray(positive_groups).ravel(), np.asarray(negative_groups).ravel()
    if pos.shape != pos_groups.shape or neg.shape != neg_groups.shape:
        raise ValueError("each score needs one group label")
    weighted, pairs = 0.0, 0
    for group in np.intersect1d(pos_groups, neg_groups):
        p, n = pos[pos_groups == group], neg[neg_groups == group]
        weighted += auroc(p, n) * p.size * n.size
        pairs += p.size * n.size
    return weighted / pairs if pairs else float("nan")
