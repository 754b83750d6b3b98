"""Which object: scores comparable across objects, as probabilities calibrated on labelled scenes.

Every candidate object of a library is estimated on the same scene (``tactile6d.estimation.identifier``); its best
pose leaves a few numbers, the **features** (``FEATURES``, lower is better):

- ``loss`` (mm): the pose's fit of the sensors' contacts (the rank step's loss: the optimiser's, or
  the refined pose's surface residual);
- ``penetration`` (mm): the deepest press of the object into any sensor's body at that pose;
- ``agreement`` (no unit): the render-and-compare cost of that pose against the observed contact
  patches (``render_and_compare.agreement_to_cost`` with the rank settings' weights; 1 = masks that do not
  overlap at all).

An object is scored ``s = w . f`` and the library's objects are turned into probabilities by a
conditional logit, ``p_o = exp(-s_o) / sum_k exp(-s_k)`` over the objects that matched at all (an object
whose database fits no tuple of the sensors' distances gets p = 0). The weights ``w`` (F,) >= 0 are
fitted by maximum likelihood on scenes whose object is known (``fit_weights``): generated scenes of
their own (stage calibrate_identify), never the test set. Fitted weights put the features on one scale, so that scores are comparable
across objects and scenes, and the probabilities are confidences fitted to those labelled scenes.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from tactile6d.core.errors import InputError

FEATURES = ("loss", "penetration", "agreement")


def features_to_scores(features: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(..., F) features and (F,) weights -> (...,) scores ``w . f`` (lower is better); NaN
    features (objects that matched nothing) give +inf."""
    features = np.asarray(features, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    if features.shape[-1] != weights.shape[0]:
        raise InputError(f"{features.shape[-1]} features per object but {weights.shape[0]} weights")
    scores = np.nan_to_num(features, nan=0.0) @ weights
    return np.where(np.isnan(features).any(axis=-1), np.inf, scores)


def scores_to_probabilities(scores: np.ndarray) -> np.ndarray:
    """(..., O) scores -> (..., O) probabilities ``softmax(-scores)`` over the last axis; +inf gives 0.
    A row with no finite score gives all zeros."""
    scores = np.asarray(scores, dtype=np.float64)
    finite = np.isfinite(scores)
    low = np.where(finite, scores, np.inf).min(axis=-1, keepdims=True)
    low = np.where(np.isfinite(low), low, 0.0)
    e = np.exp(-np.where(finite, scores - low, np.inf))  # exp(-inf) = 0: no overflow, no match
    total = e.sum(axis=-1, keepdims=True)
    return np.divide(e, total, out=np.zeros_like(e), where=total > 0)


def negative_log_likelihood(weights: np.ndarray, features: np.ndarray, truth: np.ndarray) -> float:
    """Mean -log p(true object) over S scenes: features (S, O, F) (NaN rows: no match), truth (S,)
    the true object's index. A scene whose true object did not match is skipped (no weights can help it)."""
    scores = features_to_scores(features, weights)
    rows = np.arange(len(truth))
    usable = np.isfinite(scores[rows, truth])
    if not usable.any():
        raise InputError("no scene's true object matched: nothing to calibrate on")
    s = scores[usable]
    t = truth[usable]
    low = np.where(np.isfinite(s), s, np.inf).min(axis=1)
    log_total = np.log(np.exp(-np.where(np.isfinite(s), s - low[:, None], np.inf)).sum(axis=1)) - low
    return float(np.mean(s[np.arange(len(t)), t] + log_total))


def fit_weights(features: np.ndarray, truth: np.ndarray, l2: float = 1e-3) -> np.ndarray:
    """Maximum-likelihood weights (F,) >= 0 of the conditional logit (module docstring).

    features (S, O, F) for S labelled scenes and O candidate objects (NaN rows: no match); truth (S,)
    int, each scene's true object. l2: a small ridge on the weights, which keeps them finite when the
    scenes are separable (every true object already scores best), where the likelihood alone would
    push them to infinity.
    """
    features = np.asarray(features, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.int64)
    if features.ndim != 3 or truth.shape != features.shape[:1] or features.shape[1] < 2:
        raise InputError(f"need features (S, O >= 2, F) and truth (S,), got {features.shape} and {truth.shape}")
    if truth.min() < 0 or truth.max() >= features.shape[1]:
        raise InputError(f"true object indices must lie in [0, {features.shape[1]})")
    n = features.shape[2]

    def objective(w):
        return negative_log_likelihood(w, features, truth) + l2 * float(w @ w)

    result = minimize(objective, np.ones(n), method="L-BFGS-B", bounds=[(0.0, None)] * n)
    return np.asarray(result.x, dtype=np.float64)


def confusion_matrix(truth: np.ndarray, predicted: np.ndarray, n_objects: int) -> np.ndarray:
    """(O, O) int counts: row = true object, column = the object identified first, over S scenes
    (truth, predicted (S,) indices in [0, O))."""
    truth, predicted = np.asarray(truth, dtype=np.int64), np.asarray(predicted, dtype=np.int64)
    if truth.shape != predicted.shape or (truth.size and (min(truth.min(), predicted.min()) < 0
                                                          or max(truth.max(), predicted.max()) >= n_objects)):
        raise InputError(f"need truth and predicted indices of one shape in [0, {n_objects})")
    matrix = np.zeros((n_objects, n_objects), dtype=np.int64)
    np.add.at(matrix, (truth, predicted), 1)
    return matrix
