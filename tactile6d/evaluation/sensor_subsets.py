"""Accuracy against the number of sensors: every scene estimated again from each subset of its sensors.

A scene with L sensors gives, for a count l <= L, the C(L, l) subsets of l sensors (3 singles, 3 pairs
and the triple for L = 3). Each subset is one estimate of the online estimator and one row of errors
(``scoring.scene_errors``; contact accuracy counts the subset's sensors only); the rows of a count
are summarised per object and averaged like Table I (``scoring.summarise_by_object``). The
sensor_study stage (ours vs baseline) and the ablation stage (the accuracy switches) both run this.
``estimate_and_score`` (one estimate and its row of errors) is shared with scripts/eval_accuracy.py;
``score_scene_subsets`` (one scene, every subset of a count) and ``summarise_subset_rows`` (the rows of
every scene of a count -> Table I's average row) are the two halves of a sensor-count evaluation;
``score_scene_task`` is the first as a task for worker processes (``tactile6d.runtime.executor``), with
``scene_task_input`` to make its scene argument: sensor_study and ablation spread their scenes over
workers with them.
"""

from __future__ import annotations

import itertools
import time
import warnings
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
from omegaconf import OmegaConf

from tactile6d.core.errors import NoMatch
from tactile6d.estimation.estimator import Estimator
from tactile6d.evaluation import scoring
from tactile6d.evaluation.metric_table import ERROR_KEYS
from tactile6d.perception.inputs import UnderdeterminedPoseWarning
from tactile6d.runtime.executor import process_cache
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


def scene_task_input(scenes: Mapping[str, np.ndarray], s: int) -> dict:
    """Scene ``s`` of a ``scenes`` artifact as ``score_scene_task`` takes it: ``object`` (str),
    ``T_world_object`` (4, 4), ``T_world_sensors`` (L, 4, 4), ``images`` (L, 320, 240, 3) uint8 and
    ``backgrounds`` (L, 320, 240, 3) uint8, the sensors' own no-contact images, or None."""
    return {"object": str(scenes["objects"][s]), "T_world_object": scenes["T_world_object"][s],
            "T_world_sensors": scenes["T_world_sensors"][s], "images": scenes["images"][s],
            "backgrounds": scene_backgrounds(scenes, s)}


def score_scene_task(run: str, name: str, cfg_container: dict, scene: dict, counts: tuple[int, ...]
                     ) -> dict[int, SubsetRows]:
    """One task: a scene (``scene_task_input``) estimated from every subset of each of ``counts`` of its
    sensors with the estimators of config ``name`` -> count -> its rows (``score_scene_subsets``).

    run: a token of the stage run, so that a worker process that ran an earlier one reloads (the artifacts
    may have changed); name: what the config is called (an ablation variant, a method); cfg_container: that
    whole config as plain containers (``core.config.config_for_workers``). The config's estimators (one per
    object, loaded when first needed) and the objects' references are kept per process (``process_cache``),
    one config's estimators at a time, so that a process holds no more than one config's library.
    """
    loaded = process_cache(("scene estimators", run, name), lambda: (OmegaConf.create(cfg_container), {}),
                           slot="scene estimators")
    references = process_cache(("scene references", run), dict, slot="scene references")
    cfg, estimators = loaded
    artifacts = cfg.paths.artifacts_dir
    obj = str(scene["object"])
    if obj not in estimators:
        estimators[obj] = Estimator.from_artifacts(obj, artifacts, cfg)
    if obj not in references:
        references[obj] = scoring.load_object_reference(artifacts, obj)
    return {L: score_scene_subsets(estimators[obj], scene["T_world_sensors"], scene["images"], scene["T_world_object"],
                                   references[obj], L, scene["backgrounds"])
            for L in counts}
