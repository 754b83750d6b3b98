"""Stage calibrate_confidence: fit the estimate's confidence, P(ADI of the best pose < 1 cm), on scenes of its own.

Reads ``artifacts/scenes/confidence.h5`` (stage make_confidence_scenes, drawn from ``confidence.scenes``),
every object's artifacts that the online estimator loads (``Estimator.from_artifacts``), and config
sections ``confidence``, ``select``, ``optimize``, ``rank``, ``render.background``. Estimates every scene
as a user does (the estimator, its default method, each scene's own no-contact images when the set has
them), measures the best pose's ADI against the truth, and fits ``tactile6d.estimation.confidence``'s logistic model
on the ranked poses' features. Writes ``artifacts/confidence/model.json`` (what the estimator loads),
``artifacts/confidence/fit.json`` (per scene: features, outcome, probability, the ranked poses' scores and
distances from the best) and
``artifacts/metrics/confidence.json`` (on its own scenes: AUROC, Brier score, reliability bins).

One executor task per scene (``tactile6d.runtime.executor``): ``executor.workers`` local processes by
default, a Dask cluster's workers when ``executor.address`` names one; each worker process loads an object's
estimator once. The rows come back in scene order, so the fit is the same wherever the tasks ran.
"""

from __future__ import annotations

import sys
import uuid
import warnings

import numpy as np
from omegaconf import OmegaConf

from tactile6d.core import metrics
from tactile6d.core.config import config_for_workers
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json, write_text
from tactile6d.estimation import confidence
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.evaluation.sensor_subsets import scene_task_input
from tactile6d.perception import photometric
from tactile6d.runtime.executor import executor_from_config, process_cache
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed

SCENE_SET = "confidence"


def confidence_scene_task(run: str, cfg_container: dict, scene: dict) -> tuple:
    """One task: a scene (``sensor_subsets.scene_task_input``) estimated as a user does -> (features (F,), ADI of
    the best pose (m), the ranked poses' scores, their distances from the best, light warnings), or None when
    nothing was ranked. The object's estimator and reference are kept per process (``process_cache``)."""
    cfg = process_cache(("confidence config", run), lambda: OmegaConf.create(cfg_container), slot="confidence config")
    obj = str(scene["object"])
    estimator, points, ref = process_cache(
        ("confidence estimator", run, obj), lambda: _object_state(cfg, obj), slot="confidence estimator")
    light_warnings = 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = estimator.estimate(scene["T_world_sensors"], scene["images"], scene["backgrounds"])
    for w in caught:  # a drifted light is expected on these scenes: counted; anything else shown
        if issubclass(w.category, photometric.LightWarning):
            light_warnings += 1
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if len(est.poses) == 0:  # nothing ranked: no confidence to learn from
        return None, light_warnings
    adi = float(metrics.adi(ref.points, est.poses[0], scene["T_world_object"], ref.tree))
    distances = confidence.distances_from_best(points, est.poses)
    return (confidence.features(est.scores, distances), adi, est.scores, distances), light_warnings


def _object_state(cfg, obj: str):
    """An object's estimator, its spread points (``confidence.spread_points``) and its scoring reference."""
    estimator = Estimator.from_artifacts(obj, cfg.paths.artifacts_dir, cfg)
    return estimator, confidence.spread_points(estimator.points), scoring.load_object_reference(cfg.paths.artifacts_dir, obj)


def main(argv: list[str] | None = None) -> int:
    _, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    workers = int(cfg.executor.workers)
    if workers < 1:
        raise ConfigError(f"executor.workers must be >= 1, got {workers}")
    artifacts = cfg.paths.artifacts_dir
    scenes = read_artifact(layout.scenes_file(artifacts, SCENE_SET), "scenes")
    objects = np.asarray(scenes["objects"]).astype(str)
    # Object by object (each worker then loads an object's estimator about once), in the fit's row order.
    order = [int(s) for obj in dict.fromkeys(objects.tolist()) for s in np.flatnonzero(objects == obj)]
    n = len(order)
    # The solver's JAX device count is set once per process, before any estimate (gd only).
    initargs = (str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    with executor_from_config(cfg, max(1, min(workers, n)), initializer=use_cpu_devices_for,
                              initargs=initargs) as executor:
        results = executor.map(confidence_scene_task, [uuid.uuid4().hex] * n, [config_for_workers(cfg)] * n,
                               [scene_task_input(scenes, s) for s in order], desc="confidence scenes")
    rows = [(str(scenes["names"][s]), *row) for s, (row, _) in zip(order, results) if row is not None]
    light_warnings = sum(count for _, count in results)

    x = np.array([r[1] for r in rows])
    success = np.array([r[2] < confidence.SUCCESS_ADI for r in rows])
    if success.all() or not success.any():
        raise ConfigError(f"the {len(rows)} confidence scenes are all {'right' if success.all() else 'wrong'}: "
                         "nothing to calibrate on; make confidence.scenes harder or larger")
    model = confidence.fit_model(x, success, float(cfg.confidence.ambiguity_ratio), float(cfg.confidence.ridge))
    p = model.probability(x)
    summary = {
        "n_scenes": len(rows), "n_right": int(success.sum()), "n_light_warnings": light_warnings,
        "auroc": confidence.auroc(p, success), "brier": confidence.brier(p, success),
        "reliability": confidence.reliability(p, success),
    }
    print(f"confidence: {len(rows)} scenes, {int(success.sum())} right (ADI < 1 cm); on them AUROC "
          f"{summary['auroc']:.3f}, Brier {summary['brier']:.3f}; weights "
          + ", ".join(f"{f} {w:+.2f}" for f, w in zip(model.features, model.weights)))
    write_text(layout.confidence_model_file(artifacts), model.to_json())
    # Scores and distances too, so that other features of the ranked poses can be studied without re-estimating.
    write_json(layout.confidence_model_file(artifacts).with_name("fit.json"), {
        name: {"features": dict(zip(confidence.FEATURES, map(float, xi))), "adi_m": adi, "probability": float(pi),
               "scores": scores.tolist(), "distances_m": distances.tolist()}
        for (name, xi, adi, scores, distances), pi in zip(rows, p)})
    write_json(layout.metrics_file(artifacts, "confidence"), summary)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
