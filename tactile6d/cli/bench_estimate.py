"""``tactile6d bench estimate``: seconds per estimate on the paper's triplets, and peak memory.

Runs the online estimator (``tactile6d.estimation.estimator``) on the paper's triplets (L = 3) of every object
whose artifacts exist in ``--artifacts`` (or of the ``--object`` ones), in three configurations: the
default (the composed config with any overrides given), the baseline (``select.method=baseline``) and
the faithful path (``preset=paper``: the paper's method end to end, with its 700-step gradient
descent, on the first ``--faithful-scenes`` triplets only since it is slow; docs/speed.md). Each configuration is warmed up on
one triplet first (library start-up, JAX compilation), then each triplet is timed once.

Prints the per-step medians of each configuration, then, as its last line, one JSON object with
``default_median_s``, ``baseline_median_s``, ``faithful_median_s`` (null for a configuration that could
not run, with the reason under ``skipped``), the per-step medians, ``peak_rss_mb`` (the process's peak
resident memory) and the 1-minute load average, since wall-clock times depend on what else runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

import numpy as np

from tactile6d.cli import description
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, InputError
from tactile6d.core.settings import Settings
from tactile6d.data.hdf5 import read_scene_dir
from tactile6d.data.third_party import DataStore, group_files, group_names
from tactile6d.estimation.estimator import STEPS, Estimator
from tactile6d.estimation.optimize import use_cpu_devices


def paper_triplets(store: DataStore, objects: list[str]) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(object, scene name, T_world_sensors (3, 4, 4), images (3, 320, 240, 3)) of each object's triplets."""
    with_triplets = {g.split(":", 1)[1] for g in group_names() if g.startswith("triplets:")}
    out = []
    for obj in objects:
        if obj not in with_triplets:
            continue
        for folder in sorted({store.path(r).parent for r in group_files(f"triplets:{obj}")}):
            T, images = read_scene_dir(folder)
            out.append((obj, f"{obj}/{folder.name}", T, images))
    return out


def load_estimators(objects: list[str], artifacts: str, cfg) -> tuple[dict[str, Estimator], dict[str, str]]:
    """Estimators (with cfg's settings) of the objects whose artifacts load, and why the others do not."""
    loaded, missing = {}, {}
    for obj in objects:
        try:
            loaded[obj] = Estimator.from_artifacts(obj, artifacts, cfg)
        except ArtifactError as exc:
            missing[obj] = str(exc)
    return loaded, missing


def time_configuration(estimators: dict[str, Estimator], scenes: list) -> dict[str, list[float]]:
    """Warm up on the first scene, then time one estimate per scene -> seconds per step, one list each."""
    obj, _, T, images = scenes[0]
    estimators[obj].estimate(T, images)
    seconds = {step: [] for step in (*STEPS, "total")}
    for obj, _, T, images in scenes:
        result = estimators[obj].estimate(T, images)
        for step, value in result.seconds.items():
            seconds[step].append(value)
    return seconds


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d bench estimate", description=description(__doc__))
    parser.add_argument("--object", action="append", default=None, help="object to include (repeatable; default: all)")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--faithful-scenes", type=int, default=2, help="triplets timed on the gd path (0: skip)")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value for all three configurations")
    args = parser.parse_args(argv)

    cfg = compose_config(args.overrides)
    use_cpu_devices(int(cfg.optimize.cpu_devices))  # the faithful configuration runs the gd solver
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    objects = args.object or list(cfg.objects.names)
    variants = {
        "default": Settings.from_cfg(cfg),
        "baseline": Settings.from_cfg(compose_config([*args.overrides, "select.method=baseline"])),
        "faithful": Settings.from_cfg(compose_config(["preset=paper", *args.overrides])),
    }

    # The default's artifacts (for method ours: latents and the autoencoder too); else the baseline's.
    estimators, missing = load_estimators(objects, artifacts, cfg)
    skipped = {}
    if not estimators:
        reason = f"method {cfg.select.method} lacks artifacts: {next(iter(missing.values()), 'no objects given')}"
        baseline_cfg = compose_config([*args.overrides, "select.method=baseline"])
        estimators, missing = load_estimators(objects, artifacts, baseline_cfg)
        if not estimators:
            first = next(iter(missing.values()), "no objects given")
            raise ArtifactError(f"no object has its artifacts in {artifacts} (first problem: {first})")
        skipped = {"default": reason}
        if cfg.select.method == "ours":
            skipped["faithful"] = reason
    scenes = paper_triplets(DataStore(cfg.paths), list(estimators))
    if not scenes:
        raise InputError(f"none of {', '.join(estimators)} has triplets in the paper's set")
    print(f"{len(scenes)} triplets of {len(estimators)} objects ({', '.join(estimators)})"
          + (f"; without artifacts: {', '.join(missing)}" if missing else ""))

    results = {}
    for name, settings in variants.items():
        if name in skipped:
            print(f"{name}: skipped ({skipped[name]})")
            continue
        chosen = scenes[: args.faithful_scenes] if name == "faithful" else scenes
        if not chosen:
            skipped[name] = "--faithful-scenes 0"
            continue
        t0 = time.perf_counter()
        seconds = time_configuration({o: e.with_settings(settings) for o, e in estimators.items()}, chosen)
        medians = {step: float(np.median(v)) for step, v in seconds.items()}
        results[name] = {"median_s": medians["total"], "steps_median_s": medians, "n_scenes": len(chosen),
                         "method": settings.select.method, "solver": settings.optimize.solver}
        steps = ", ".join(f"{s} {medians[s]:.3f}" for s in STEPS)
        print(f"{name} ({settings.select.method}, {settings.optimize.solver}): median {medians['total']:.3f} s "
              f"per estimate over {len(chosen)} triplets [{steps}] ({time.perf_counter() - t0:.0f} s in all)")

    summary = {f"{name}_median_s": results[name]["median_s"] if name in results else None for name in variants}
    summary.update(
        steps_median_s={name: r["steps_median_s"] for name, r in results.items()},
        n_scenes={name: r["n_scenes"] for name, r in results.items()},
        N=int(cfg.select.N),
        objects=list(estimators),
        skipped=skipped,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        load_average_1min=os.getloadavg()[0],
        cpu_count=os.cpu_count(),
    )
    print(json.dumps(summary))
    return 0
