"""How far an estimate can be trusted: a calibrated probability that its best pose is right, and a
flag when several distinct poses explain the contacts about equally well.

"Right" means the best pose's ADI (``metrics.adi``) is under ``SUCCESS_ADI`` (1 cm). The probability is
a logistic regression on two features of the ranked poses alone (no ground truth), fitted by the
stage ``calibrate_confidence`` on generated scenes of its own (``confidence.scenes``):

- ``rival_gap``: log10 of how much worse, relative to the best pose's score, the best *rival* scores,
  a rival being a ranked pose farther than ``RIVAL_DISTANCE`` from the best (no rival: ``RIVAL_GAP_MAX``).
  A rival that scores nearly as well is a second explanation of the same contacts.
- ``spread_cm``: the largest ADI distance (cm) from the best pose to any other ranked pose: how far
  apart the top-k lie.

Both are free of the number of sensors and of the score's scale, so that estimates with different L
and objects compare. The best pose's score itself (per sensor) separated right from wrong no better than
chance on the generated sets (AUROC 0.34-0.67), and in the fit it lowered offaxis's held-out AUROC
from 0.91 to 0.68 (docs/confidence.md): it is not a feature.

The distance between two ranked poses is the ADI with one of them taken as the truth, on a fixed,
evenly strided subset of the object's points (``spread_points``), so that the online estimator (which
holds the database points) and the evaluation (which reads the same surface file) compute the same
number.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

import numpy as np

from tactile6d.core import metrics

SUCCESS_ADI = 0.01  # m: the success the confidence predicts
# m: two ranked poses this far apart (ADI) are different explanations. Below SUCCESS_ADI, since the best
# pose's own error adds to it: with 1 cm the confidence told right from wrong on the generated sets with
# AUROC 0.65-0.97 (offaxis the lowest), with 0.75 cm 0.93-0.96 (docs/confidence.md).
RIVAL_DISTANCE = 0.0075
RIVAL_GAP_MAX = 10.0  # relative score gap given when no ranked pose is a rival (log10: 1)
RIVAL_GAP_MIN = 1e-3  # floor of the relative gap before its log (equal scores)
SPREAD_POINTS = 500  # object points that the distance between two ranked poses is measured on
FEATURES = ("rival_gap", "spread_cm")


def spread_points(points: np.ndarray, n: int = SPREAD_POINTS) -> np.ndarray:
    """An even, deterministic subset of an object's points: (M, 3) -> (min(M, n), 3), every ceil(M/n)-th."""
    points = np.asarray(points, dtype=np.float64)
    return points[:: max(1, -(-len(points) // n))]


def distances_from_best(points: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """ADI distance (m) of each ranked pose from the best: points (N, 3) object frame, poses (K, 4, 4)
    best first -> (K,), 0 for the best itself. NaN rows of ``poses`` (ranked.h5 pads with them) must be
    cut off before."""
    poses = np.asarray(poses, dtype=np.float64)
    if len(poses) == 0:
        return np.zeros(0)
    return metrics.adi(points, poses, poses[0])


def rival_gaps(scores: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """Each rival's score gap relative to the best's: scores (K,), distances (K,) from the best -> (R,),
    in rank order, for the poses farther than RIVAL_DISTANCE from the best. A non-positive best score
    (a perfect fit) counts as the smallest positive float, so that any worse rival has a large gap."""
    scores = np.asarray(scores, dtype=np.float64)
    rivals = np.asarray(distances) > RIVAL_DISTANCE
    return (scores[rivals] - scores[0]) / max(float(scores[0]), np.finfo(float).tiny)


def features(scores: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """The confidence's features (``FEATURES`` order) of one estimate: scores (K,) and distances (K,)
    from the best, K >= 1 -> (2,)."""
    scores = np.asarray(scores, dtype=np.float64)
    if scores.size == 0:
        raise ValueError("an estimate without poses has no confidence")
    gaps = rival_gaps(scores, distances)
    gap = float(gaps.min()) if gaps.size else RIVAL_GAP_MAX
    return np.array([
        np.log10(np.clip(gap, RIVAL_GAP_MIN, RIVAL_GAP_MAX)),
        100.0 * float(np.max(distances)),
    ])


def distinct_poses(scores: np.ndarray, distances: np.ndarray, ratio: float) -> np.ndarray:
    """The poses that explain the contacts about equally well, as indices into the ranking: the best
    and every rival whose score is within ``ratio`` of the best's (relative). (K,), (K,) -> (D,), D >= 1."""
    rivals = np.flatnonzero(np.asarray(distances) > RIVAL_DISTANCE)
    close = rivals[rival_gaps(scores, distances) <= ratio]
    return np.concatenate([[0], close]).astype(np.int64)


@dataclass(frozen=True)
class ConfidenceModel:
    """A logistic regression on standardised features: P = sigmoid(bias + weights . (x - mean) / std).

    weights, mean, std: one per ``features`` name; ambiguity_ratio: the relative score gap under which a
    rival counts as explaining the contacts about equally well (``distinct_poses``)."""

    features: tuple[str, ...]
    weights: tuple[float, ...]
    bias: float
    mean: tuple[float, ...]
    std: tuple[float, ...]
    ambiguity_ratio: float

    def probability(self, x: np.ndarray) -> np.ndarray:
        """(..., F) features -> (...) P(ADI of the best pose < SUCCESS_ADI)."""
        z = (np.asarray(x, dtype=np.float64) - np.asarray(self.mean)) / np.asarray(self.std)
        return sigmoid(self.bias + z @ np.asarray(self.weights))

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True) + "\n"

    @classmethod
    def from_json(cls, text: str) -> ConfidenceModel:
        raw = json.loads(text)
        if tuple(raw.get("features", ())) != FEATURES:
            raise ValueError(f"a confidence model on features {raw.get('features')}, this code computes "
                             f"{list(FEATURES)}: re-run the stage calibrate_confidence")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()})


def sigmoid(z: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(-z)), without overflow for large |z|."""
    z = np.asarray(z, dtype=np.float64)
    return np.exp(-np.logaddexp(0.0, -z))


def fit_logistic(x: np.ndarray, y: np.ndarray, ridge: float = 1.0, iterations: int = 50) -> tuple[np.ndarray, float]:
    """Maximum a-posteriori logistic regression by Newton's method: x (N, F) standardised features,
    y (N,) 0/1 -> (weights (F,), bias). ``ridge`` is the precision of a zero-mean Gaussian prior on the
    weights (not the bias): with few failures to learn from, it keeps a feature that separates the fit
    set perfectly from driving its weight, and the probabilities, to infinity."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    a = np.hstack([np.ones((len(x), 1)), x])
    penalty = np.diag([0.0] + [ridge] * x.shape[1])
    beta = np.zeros(a.shape[1])
    for _ in range(iterations):
        p = sigmoid(a @ beta)
        gradient = a.T @ (p - y) + penalty @ beta
        hessian = (a * (p * (1 - p))[:, None]).T @ a + penalty + 1e-9 * np.eye(a.shape[1])
        step = np.linalg.solve(hessian, gradient)
        beta -= step
        if np.max(np.abs(step)) < 1e-10:
            break
    return beta[1:], float(beta[0])


def fit_model(x: np.ndarray, success: np.ndarray, ambiguity_ratio: float, ridge: float = 1.0) -> ConfidenceModel:
    """A ConfidenceModel from raw features (N, F) in ``FEATURES`` order and successes (N,) bool."""
    x = np.asarray(x, dtype=np.float64)
    mean, std = x.mean(axis=0), x.std(axis=0)
    std = np.where(std > 0, std, 1.0)
    weights, bias = fit_logistic((x - mean) / std, np.asarray(success, dtype=np.float64), ridge)
    return ConfidenceModel(FEATURES, tuple(map(float, weights)), bias, tuple(map(float, mean)),
                           tuple(map(float, std)), float(ambiguity_ratio))


def assess(model: ConfidenceModel, points: np.ndarray, poses: np.ndarray, scores: np.ndarray) -> tuple[float, np.ndarray]:
    """One estimate's confidence and distinct poses: points (N, 3) from ``spread_points``, poses (K, 4, 4)
    and scores (K,) best first, K >= 1 -> (P(ADI of the best < SUCCESS_ADI), indices of ``distinct_poses``)."""
    distances = distances_from_best(points, poses)
    probability = float(model.probability(features(scores, distances)))
    return probability, distinct_poses(scores, distances, model.ambiguity_ratio)


def brier(probability: np.ndarray, success: np.ndarray) -> float:
    """Mean squared difference between predicted probability and outcome (0 best; 0.25 for a constant 0.5)."""
    return float(np.mean((np.asarray(probability) - np.asarray(success, dtype=np.float64)) ** 2))


def reliability(probability: np.ndarray, success: np.ndarray, n_bins: int = 5) -> list[dict]:
    """The reliability diagram's bins: equal-width bins of predicted probability on [0, 1]; for each
    non-empty one, its range, count, mean prediction and observed success rate."""
    p, y = np.asarray(probability, dtype=np.float64), np.asarray(success, dtype=np.float64)
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    which = np.clip(np.digitize(p, edges[1:-1]), 0, n_bins - 1)
    out = []
    for b in range(n_bins):
        inside = which == b
        if inside.any():
            out.append({"low": float(edges[b]), "high": float(edges[b + 1]), "count": int(inside.sum()),
                        "predicted": float(p[inside].mean()), "observed": float(y[inside].mean())})
    return out


def auroc(probability: np.ndarray, success: np.ndarray) -> float:
    """AUROC of the probability for success (``metrics.auroc``); NaN when one class is absent."""
    p, ok = np.asarray(probability, dtype=np.float64), np.asarray(success, dtype=bool)
    return metrics.auroc(p[ok], p[~ok])
