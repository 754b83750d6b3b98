"""One more touch for the ambiguous estimates of a scene set: where the poses differ, or anywhere flat.

    python scripts/touch_to_tell_apart.py --artifacts artifacts --scenes validation kinematic [override ...]

Each scene is estimated with the default estimator; those whose estimate is ambiguous (``Estimate.distinct``
holds more than the best) get a fourth touch, two ways: where the distinct poses differ
(``disambiguation.touch_to_tell_apart``, which falls back on the flattest reachable spot where no point tells
them apart), and, to compare, on the flattest reachable spot of the best pose whatever the rivals (the same
function with ``enough`` and ``least`` 0: no separation asked). Each touch is made as a hand
makes it, a guarded move along its approach line against the object at its true pose
(``disambiguation.touch_as_met``), the image rendered there by the project's renderer over the set's
no-contact image, the sensor's pose reported with a kinematic error drawn like the set's where the set has one
(``pose_error_*``); the light of ``variation``'s drift is not drawn on the new image. Then ``disambiguation.choose``
re-scores the distinct poses with the four sensors. A touch the object would run into (the renderer refuses a
body inside the sensor) leaves the estimate as it was.

Per set it prints the scenes, how many were ambiguous, and over those the best pose's positional error
(mean, median, cm) and how many were 1 cm ADI or more off: before, after the touch where the poses differ,
after the touch anywhere flat, with how many touches were made. ``--out FILE`` writes the per-scene rows
(JSON). A study: it writes nothing else.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core import geometry as g  # noqa: E402
from tactile6d.core import metrics  # noqa: E402
from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.errors import InputError, NoMatch  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.data.third_party import DataStore  # noqa: E402
from tactile6d.estimation import disambiguation  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.optimize import use_cpu_devices_for  # noqa: E402
from tactile6d.evaluation import scoring  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.render import DigitRenderer, load_background_bgr  # noqa: E402

WRONG_ADI = 0.01  # m: an estimate 1 cm ADI or more off is wrong (the confidence's event)


def hand_error(rng: np.random.Generator, sigma_m: float, sigma_rad: float) -> np.ndarray:
    """A sensor-pose error (4, 4) drawn as the kinematic sets draw theirs: per axis in the sensor's frame."""
    return g.make_pose(g.rotvec_to_rotmat(rng.normal(0.0, sigma_rad, 3)), rng.normal(0.0, sigma_m, 3))


def touched_choice(estimator, renderer, mesh, T_true, poses, T_sensors, images, touch, reported_error):
    """The distinct poses chosen among after ``touch`` (None: no touch, or the object would run into the
    sensor) -> (best pose (4, 4) or None, whether the sensor met the object)."""
    if touch is None:
        return None, False
    T_met, met = disambiguation.touch_as_met(mesh, T_true, touch)
    try:
        image = renderer.render(mesh, T_true, T_met, 7).image
    except InputError:  # the object inside the sensor's body: the hand would have run into it
        return None, met
    T_reported = T_met if reported_error is None else T_met @ reported_error
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a touch that meets nothing warns of an untouched sensor: as meant
        choice = disambiguation.choose(estimator, poses, np.concatenate([T_sensors, T_reported[None]]),
                                  np.concatenate([images, image[None]]))
    return choice.best, met


def summary(rows: list[dict]) -> dict:
    """Per-scene rows (positional errors m, ADIs m, before / informed / flat) -> mean and median cm, wrong."""
    out = {"ambiguous": len(rows)}
    for key in ("before", "informed", "flat"):
        position = np.array([r[f"{key}_position"] for r in rows], dtype=float)
        adi = np.array([r[f"{key}_adi"] for r in rows], dtype=float)
        out[key] = {"mean_cm": float(np.mean(position) * 100) if rows else float("nan"),
                    "median_cm": float(np.median(position) * 100) if rows else float("nan"),
                    "wrong": int(np.count_nonzero(adi >= WRONG_ADI))}
        if key != "before":
            out[key]["touched"] = int(sum(r[f"{key}_touched"] for r in rows))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", default=["validation"])
    parser.add_argument("--seed", type=int, default=0, help="the new sensors' kinematic errors")
    parser.add_argument("--out", help="write the per-scene rows here (JSON)")
    parser.add_argument("overrides", nargs="*")
    args = parse_with_overrides(parser)
    cfg = compose_config(list(args.overrides))
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    renderer = DigitRenderer.from_config(cfg.render, load_background_bgr(cfg, DataStore(cfg.paths)), workers=1)
    sigma_m, sigma_rad = float(cfg.sensors.pose_sigma_mm) / 1000, np.radians(float(cfg.sensors.pose_sigma_deg))
    rng = np.random.default_rng(args.seed)
    every = {}
    for name in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, name), "scenes")
        kinematic = "pose_error_rotvec" in scenes
        estimators, references, rows = {}, {}, []
        for s, obj in enumerate(str(o) for o in scenes["objects"]):
            if obj not in estimators:
                estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
                references[obj] = scoring.load_object_reference(args.artifacts, obj)
            estimator, reference = estimators[obj], references[obj]
            T_true, T_sensors = np.asarray(scenes["T_world_object"][s]), np.asarray(scenes["T_world_sensors"][s])
            images = np.asarray(scenes["images"][s])
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    estimate = estimator.estimate(T_sensors, images)
            except NoMatch:
                continue
            if estimate.distinct is None or len(estimate.distinct) < 2:
                continue
            poses = estimate.poses[estimate.distinct]
            reported_error = hand_error(rng, sigma_m, sigma_rad) if kinematic else None
            row = {"set": name, "scene": s, "object": obj, "distinct": len(poses)}
            for key, enough, least in (("informed", 0.01, 0.003), ("flat", 0.0, 0.0)):
                touch = disambiguation.touch_to_tell_apart(estimator.surface, poses, T_sensors, enough=enough,
                                                           least=least)
                best, met = touched_choice(estimator, renderer, estimator.mesh, T_true, poses, T_sensors, images, touch,
                                           reported_error)
                row[f"{key}_touched"], row[f"{key}_met"] = best is not None, bool(met)
                best = poses[0] if best is None else best
                row[f"{key}_position"] = float(np.linalg.norm(best[:3, 3] - T_true[:3, 3]))
                row[f"{key}_adi"] = float(metrics.adi(reference.points, best, T_true, reference.tree))
            row["before_position"] = float(np.linalg.norm(poses[0][:3, 3] - T_true[:3, 3]))
            row["before_adi"] = float(metrics.adi(reference.points, poses[0], T_true, reference.tree))
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
        every[name] = rows
        result = {"set": name, "scenes": len(scenes["objects"]), **summary(rows)}
        print(json.dumps(result), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(every, indent=1))
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
