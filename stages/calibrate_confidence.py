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
"""

from __future__ import annotations

import sys
import warnings

import numpy as np
from tqdm import tqdm

from tactile6d.core import metrics
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json, write_text
from tactile6d.estimation import confidence
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.perception import photometric
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim.scenes import scene_set_from_artifact

SCENE_SET = "confidence"


def main(argv: list[str] | None = None) -> int:
    _, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    use_cpu_devices_for(cfg.optimize.solver, cfg.optimize.cpu_devices)  # before JAX runs anything
    artifacts = cfg.paths.artifacts_dir
    scenes = scene_set_from_artifact(read_artifact(layout.scenes_file(artifacts, SCENE_SET), "scenes"))
    objects = [str(o) for o in dict.fromkeys(scenes.objects.tolist())]
    references = {o: scoring.load_object_reference(artifacts, o) for o in objects}

    rows, light_warnings = [], 0
    for obj in objects:
        estimator = Estimator.from_artifacts(obj, artifacts, cfg)
        points = confidence.spread_points(estimator.points)
        ref = references[obj]
        for s in tqdm(np.flatnonzero(scenes.objects == obj), desc=f"confidence scenes of {obj}", unit="scene"):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                est = estimator.estimate(scenes.T_world_sensors[s], scenes.images[s], scenes.backgrounds_of(s))
            for w in caught:  # a drifted light is expected on these scenes: counted; anything else shown
                if issubclass(w.category, photometric.LightWarning):
                    light_warnings += 1
                else:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            if len(est.poses) == 0:  # nothing ranked: no confidence to learn from
                continue
            adi = float(metrics.adi(ref.points, est.poses[0], scenes.T_world_object[s], ref.tree))
            distances = confidence.distances_from_best(points, est.poses)
            rows.append((str(scenes.names[s]), confidence.features(est.scores, distances), adi, est.scores, distances))

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
