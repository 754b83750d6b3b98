"""Accuracy against the number of sensors: every scene estimated again from each subset of its sensors.

A scene with L sensors gives, for a count l <= L, the C(L, l) subsets of l sensors (3 singles, 3 pairs
and the triple for L = 3). Each subset is one estimate of the online estimator and one row of errors
(``scoring.scene_errors``; contact accuracy counts the subset's sensors only); the rows of a count
are summarised per object and averaged like Table I (``scoring.summarise_by_object``). The
sensor_study stage (ours vs baseline) and the ablation stage (the accuracy switches) both run this.
``estimate_and_score`` (one estimate and its row of errors) is shared with scripts/eval_accuracy.py;
``score_scene_subsets`` (one scene, every subset of a count) and ``summarise_subset_rows`` are the two
halves of ``evaluate_sensor_count``, for callers that spread the scenes over worker processes.
"""

from __future__ import annotations

import itertools
import time
import warnings
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
from tqdm import tqdm

from tactile6d.core.errors import NoMatch
from tactile6d.estimation.estimator import Estimator
from tactile6d.evaluation import scoring
from tactile6d.evaluation.metric_table import ERROR_KEYS
from tactile6d.perception.inputs import UnderdeterminedPoseWarning
from tactile6d.sim.scenes import scene_backgrounds


class ScoredEstimate(NamedTuple):
    """One estimate and its errors: ``errors`` is ``scoring.scene_errors``' row (arrays (k,) keyed by
    ``ERROR_KEYS``); ``seconds`` the estimator's wall-clock seconds by step (``Estimate.seconds``, with
    ``total``), None when the estimate matched nothing (``NoMatch``, a failure); ``wall_seconds`` the
    wall-clock seconds of the whole call to ``estimate``, a failed one included."""

    errors: dict[str, np.ndarray]
    seconds: dict[str, float] | None
    wall_seconds: float


def estimate_and_score(
    estimator: Estimator,
    T_world_sensors: np.ndarray,
    images: np.ndarray | None,
    T_world_object: np.ndarray,
    reference: scoring.ObjectReference,
    backgrounds: np.ndarray | None = None,
) -> ScoredEstimate:
    """Estimate one scene's object pose from its sensors and score the ranked poses against the truth.

    T_world_sensors (L, 4, 4) and images (L, 320, 240, 3) uint8 (None for a method that reads none) go to
    ``estimator.estimate``, with backgrounds (L, 320, 240, 3), the sensors' own no-contact images, when
    the scene has them; T_world_object (4, 4) is the true pose; reference the object's
    (``scoring.load_object_reference``). An estimate that matches nothing (``NoMatch``) counts as a
    failure (no poses: NaN errors, ``seconds`` None), as in evaluate; bad input raises.
    """
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():  # one sensor's pose is under-determined: what the study measures
            warnings.simplefilter("ignore", UnderdeterminedPoseWarning)
            est = estimator.estimate(T_world_sensors, images, backgrounds)
        poses, n, seconds = est.poses, len(est.poses), est.seconds
    except NoMatch:  # nothing matched: a failed estimate
        poses, n, seconds = np.zeros((0, 4, 4)), 0, None
    wall_seconds = time.perf_counter() - t0
    errors = scoring.scene_errors(poses, n, T_world_object, T_world_sensors, reference.points,
                                     reference.surface, tree=reference.tree)
    return ScoredEstimate(errors, seconds, wall_seconds)


def sensor_subsets(n_sensors: int, count: int) -> list[tuple[int, ...]]:
    """The subsets of ``count`` sensors among ``n_sensors``, as sorted index tuples, in lexicographic order."""
    if not 1 <= count <= n_sensors:
        raise ValueError(f"a subset of {count} sensors among {n_sensors} does not exist")
    return list(itertools.combinations(range(n_sensors), count))


class SubsetRows(NamedTuple):
    """One scene estimated from every subset of ``count`` of its sensors (``sensor_subsets`` order):
    ``errors`` keyed by ``ERROR_KEYS``, each (n_subsets, k) (``scoring.scene_errors``' rows, stacked);
    ``seconds`` the estimator's total seconds of each estimate that matched."""

    errors: dict[str, np.ndarray]
    seconds: list[float]


def score_scene_subsets(
    estimator: Estimator,
    T_world_sensors: np.ndarray,
    images: np.ndarray,
    T_world_object: np.ndarray,
    reference: scoring.ObjectReference,
    count: int,
    backgrounds: np.ndarray | None = None,
) -> SubsetRows:
    """One scene (sensors (L, 4, 4), images (L, 320, 240, 3) uint8, true pose (4, 4), the sensors' own
    no-contact images (L, 320, 240, 3) or None) estimated from each subset of ``count`` of its L sensors by
    ``estimate_and_score``."""
    rows: dict[str, list[np.ndarray]] = {key: [] for key in ERROR_KEYS}
    seconds = []
    for subset in sensor_subsets(len(T_world_sensors), count):
        idx = list(subset)
        own = None if backgrounds is None else backgrounds[idx]
        scored = estimate_and_score(estimator, T_world_sensors[idx], images[idx], T_world_object, reference, own)
        if scored.seconds is not None:
            seconds.append(float(scored.seconds["total"]))
        for key in ERROR_KEYS:
            rows[key].append(scored.errors[key])
    return SubsetRows({key: np.stack(v) for key, v in rows.items()}, seconds)


def summarise_subset_rows(rows: Sequence[SubsetRows], objects: Sequence[str]) -> tuple[dict[str, float], list[float]]:
    """The scenes' rows (scene s of object ``objects[s]``), in scene order -> the average row of
    ``scoring.summarise_by_object`` ({} for no scenes) and the seconds of every estimate, in order."""
    if not rows:
        return {}, []
    arrays = {key: np.concatenate([r.errors[key] for r in rows]) for key in ERROR_KEYS}
    owners = np.concatenate([[str(obj)] * len(r.errors[ERROR_KEYS[0]]) for r, obj in zip(rows, objects)])
    seconds = [t for r in rows for t in r.seconds]
    return scoring.summarise_by_object(arrays, owners)["average"], seconds


def evaluate_sensor_count(
    scenes: Mapping[str, np.ndarray],
    estimators: Mapping[str, Estimator],
    references: Mapping[str, scoring.ObjectReference],
    count: int,
    desc: str = "",
    progress: bool = True,
) -> tuple[dict[str, float], list[float]]:
    """Estimate every scene from every subset of ``count`` of its sensors and summarise.

    scenes: a ``scenes`` artifact (``objects`` (S,), ``T_world_object`` (S, 4, 4), ``T_world_sensors``
    (S, L, 4, 4), ``images`` (S, L, 320, 240, 3), optionally ``backgrounds`` (S, L, 320, 240, 3)); estimators
    and references keyed by object name.
    Returns the average row of ``scoring.summarise_by_object`` (the metric keys of
    ``metric_table.SUMMARY_KEYS``; an empty dict for an empty set) and the wall-clock seconds of each
    estimate. ``desc`` labels the progress bar (``progress=False``: none, e.g. in a worker process). An estimate
    that matches nothing (``NoMatch``) counts as a failure, as in evaluate; bad input raises.
    """
    objects = [str(o) for o in scenes["objects"]]
    rows = [
        score_scene_subsets(estimators[objects[s]], scenes["T_world_sensors"][s], scenes["images"][s],
                            scenes["T_world_object"][s], references[objects[s]], count, scene_backgrounds(scenes, s))
        for s in tqdm(range(len(objects)), desc=desc or f"L={count}", unit="scene", leave=False, disable=not progress)
    ]
    return summarise_subset_rows(rows, objects)
