"""Score the online estimator on a scene set under config overrides (accuracy experiments; tune on validation only).

    python scripts/eval_accuracy.py --artifacts artifacts --scenes validation --method ours \
        select.delta_d_rule=best_n rank.refine=true

prints one JSON line: the scene set, method, overrides, the average over objects of the evaluation's
Table I figures (``tactile6d.evaluation.summarise_by_object``), the median seconds per estimate (whole
``Estimator.estimate``, and by step) and how many scenes failed. ``--proxy K`` instead draws K
geometry-only scenes per object the way ``make_scenes`` draws validation scenes (other seed, no
images: method baseline only), for quick checks before the rendered scenes exist.

Reads the artifacts only (surfaces, objects, latents, the autoencoder); writes nothing but ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.evaluation.metric_table import ERROR_KEYS
from tactile6d.evaluation.sensor_subsets import estimate_and_score
from tactile6d.runtime.script_args import parse_with_overrides
from tactile6d.sim import scenes, surface_sampling
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def proxy_scenes(artifacts: str, objects: list[str], per_object: int, seed: int) -> dict:
    import trimesh

    meshes, surfaces, database = {}, {}, {}
    for o in objects:
        art = read_artifact(layout.object_file(artifacts, o), "object")
        meshes[o] = trimesh.Trimesh(art["vertices"], art["faces"], process=False)
        surfaces[o] = surface_sampling.sample_surface(meshes[o])
        database[o] = read_artifact(layout.surface_file(artifacts, o), "surface")["points"]
    spec = scenes.ValidationSpec(scenes_per_object=per_object)
    out = scenes.generate_validation(objects, meshes, surfaces, database,
                                     lambda *a: np.zeros((spec.n_sensors, 1, 1, 3), np.uint8), spec, seed)
    return {"names": out.names, "objects": out.objects, "T_world_object": out.T_world_object,
            "T_world_sensors": out.T_world_sensors, "images": None}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", default="validation", help="scene set under artifacts/scenes (never tune on caddeo2023)")
    parser.add_argument("--proxy", type=int, default=0, help="geometry-only scenes per object instead (baseline)")
    parser.add_argument("--proxy-seed", type=int, default=101)
    parser.add_argument("--method", default="ours", choices=("ours", "baseline"))
    parser.add_argument("--objects", nargs="*", help="only these objects")
    parser.add_argument("--out", help="write per-scene errors (npz) here")
    parser.add_argument("overrides", nargs="*")
    args = parse_with_overrides(parser)

    cfg = compose_config([f"select.method={args.method}", *args.overrides])
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    if args.proxy:
        objects = args.objects or [o for o in cfg.objects.names if layout.object_file(args.artifacts, o).is_file()]
        data = proxy_scenes(args.artifacts, objects, args.proxy, args.proxy_seed)
        set_name = f"proxy{args.proxy}x{args.proxy_seed}"
    else:
        art = read_artifact(layout.scenes_file(args.artifacts, args.scenes), "scenes")
        data = {k: np.asarray(art[k]) for k in ("names", "objects", "T_world_object", "T_world_sensors", "images")}
        set_name = args.scenes
    keep = np.ones(len(data["names"]), dtype=bool) if not args.objects else np.isin(data["objects"], args.objects)

    estimators, references = {}, {}
    rows = {key: [] for key in ERROR_KEYS}
    seconds, steps, owners, failed = [], [], [], 0
    for s in np.flatnonzero(keep):
        obj = str(data["objects"][s])
        if obj not in estimators:
            estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
            references[obj] = scoring.load_object_reference(args.artifacts, obj)
        images = None if data["images"] is None else data["images"][s]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scored = estimate_and_score(estimators[obj], data["T_world_sensors"][s], images,
                                        data["T_world_object"][s], references[obj])
        if scored.seconds is None:
            failed += 1
        else:
            steps.append(scored.seconds)
        seconds.append(scored.wall_seconds)
        for key, values in rows.items():
            values.append(scored.errors[key])
        owners.append(obj)
    errors = {key: np.array(v) for key, v in rows.items()}
    summary = scoring.summarise_by_object(errors, np.array(owners))
    avg = {k: round(v, 3) for k, v in summary["average"].items() if k.endswith("top1")}
    step_medians = {k: round(float(np.median([st[k] for st in steps])), 3) for k in steps[0]} if steps else {}
    print(json.dumps({"scenes": set_name, "method": args.method, "overrides": args.overrides, "n": len(owners),
                      "failed": failed, **avg, "median_s": round(float(np.median(seconds)), 3),
                      "median_s_by_step": step_medians}))
    if args.out:
        np.savez(args.out, objects=np.array(owners), **errors)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
