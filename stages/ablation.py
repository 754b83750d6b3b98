"""Stage ablation: the effect of each accuracy switch (normals, best_n, refinement, patches) at L = 3 sensors.

Every variant of config section ``ablation.variants`` is applied to the ``select``, ``optimize`` and
``rank`` sections (``tactile6d.evaluation.ablation_variants``: method ``ours``; solver ``ablation.solver`` unless the variant
sets its own; a variant may start from a preset's sections), and each scene of the set is estimated from
all its sensors; on the scene sets of ``ablation.curves_on``, a variant of ``ablation.curves`` also from
every subset of 1, ..., L of them (``tactile6d.evaluation.sensor_subsets``, as in sensor_study). A variant of
``ablation.only_on`` runs on the scene sets it lists only; a scene set of ``ablation.variants_on`` runs
the variants it lists only. Two variants that come out as the same settings at the sensor counts they
are estimated at (e.g. the last step of the chain and ``default``; or steps that differ only in normal
settings that do not apply at L = 3, ``ablation_variants.estimator_settings_key``) are estimated once. Reads the scenes and each object's artifacts; writes
``artifacts/metrics/ablation_<set>.json``: variant -> ``L<count>`` -> the evaluation's metric names, plus
``time_s_median`` (per estimate).

One executor task per variant and scene (``tactile6d.runtime.executor``, config section ``executor``):
``ablation.workers`` local processes by default, a Dask cluster's workers when ``executor.address``
names one. A task gets its scene's arrays and reads the objects' artifacts by path (on a cluster, the
artifacts directory must be at the same absolute path on every worker); each worker process loads a
variant's estimators once and keeps one variant's at a time. The rows come back in scene order, so
every figure but ``time_s_median`` is the same wherever the tasks ran.
"""

from __future__ import annotations

import sys
import uuid

import numpy as np
from omegaconf import OmegaConf

from tactile6d.core.config import config_for_workers
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json
from tactile6d.estimation.optimize import use_cpu_devices
from tactile6d.evaluation.ablation_variants import estimator_settings_key, variant_config
from tactile6d.evaluation.sensor_subsets import scene_task_input, score_scene_task, summarise_subset_rows
from tactile6d.runtime.executor import executor_from_config
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed


def variants_on(scene_set: str, names: list[str], only_on: dict, per_set: dict | None = None) -> list[str]:
    """The variants of ``names`` that run on ``scene_set``: ``ablation.only_on`` (variant -> its sets) and
    ``ablation.variants_on`` (``per_set``: set -> its variants; a set not listed runs them all)."""
    per_set = per_set or {}
    listed = {v for variants in per_set.values() for v in variants}
    unknown = sorted((set(only_on) | listed) - set(names))
    if unknown:
        raise ConfigError(f"ablation.only_on or ablation.variants_on names variants that ablation.variants does "
                          f"not have: {unknown}")
    return [name for name in names if (name not in only_on or scene_set in only_on[name])
            and (scene_set not in per_set or name in per_set[scene_set])]


def sensor_counts(names: list[str], n_sensors: int, curves: list[str], variants: list[str]) -> dict[str, tuple[int, ...]]:
    """The variants ``names`` (of all ``variants``) -> the sensor counts each is estimated at: every count
    1..L for ``curves``, else L alone."""
    unknown = sorted(set(curves) - set(variants))
    if unknown:
        raise ConfigError(f"ablation.curves names variants that ablation.variants does not have: {unknown}")
    every = tuple(range(1, n_sensors + 1))
    return {name: every if name in curves else every[-1:] for name in names}


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    workers = int(cfg.ablation.workers)
    if workers < 1:
        raise ConfigError(f"ablation.workers must be >= 1, got {workers}")
    artifacts = cfg.paths.artifacts_dir
    only_on = OmegaConf.to_container(cfg.ablation.only_on) if cfg.ablation.only_on else {}
    per_set = OmegaConf.to_container(cfg.ablation.variants_on) if cfg.ablation.get("variants_on") else {}
    names = variants_on(args.scene_set, list(cfg.ablation.variants), only_on, per_set)
    variants = {name: variant_config(cfg, name, cfg.ablation.variants[name]) for name in names}
    scenes = read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes")
    objects = [str(o) for o in scenes["objects"]]
    n_sensors = scenes["T_world_sensors"].shape[1] if objects else 0
    # Curves only where the report draws them (ablation.curves_on); elsewhere every variant at L alone.
    curves = list(cfg.ablation.curves or []) if args.scene_set in list(cfg.ablation.curves_on or []) else []
    counts = sensor_counts(names, n_sensors, curves, list(cfg.ablation.variants))
    # Settings key at the variant's sensor counts -> the first variant with it: the others reuse its estimates.
    keys = {name: estimator_settings_key(variant_cfg, counts[name]) for name, variant_cfg in variants.items()}
    first_with = {}
    for name in names:
        first_with.setdefault(keys[name], name)
    unique = list(first_with.values())
    scene_data = [scene_task_input(scenes, s) for s in range(len(objects))]
    containers = {name: config_for_workers(variants[name]) for name in unique}
    jobs = [(name, s) for name in unique for s in range(len(objects))]  # variant-major: a worker keeps one variant's estimators
    run = uuid.uuid4().hex
    # JAX's device count is set once per process, before any estimate (the paper's variant runs the gd solver).
    with executor_from_config(cfg, workers, initializer=use_cpu_devices, initargs=(int(cfg.optimize.cpu_devices),)) as ex:
        print(f"ablation {args.scene_set}: {len(unique)} distinct variants x {len(objects)} scenes on {ex.describe()}",
              flush=True)
        rows = ex.map(score_scene_task, [run] * len(jobs), [n for n, _ in jobs], [containers[n] for n, _ in jobs],
                      [scene_data[s] for _, s in jobs], [counts[n] for n, _ in jobs], desc=f"ablation {args.scene_set}")
    by_job = dict(zip(jobs, rows))

    by_name = {}
    for name in unique:
        by_name[name] = {}
        for L in counts[name]:
            summary, seconds = summarise_subset_rows([by_job[name, s][L] for s in range(len(objects))], objects)
            summary["time_s_median"] = float(np.median(seconds)) if seconds else float("nan")
            by_name[name][f"L{L}"] = summary
            print(f"{args.scene_set} {name} L={L}: position {summary.get('pos_err_cm_top1', float('nan')):.2f} cm, "
                  f"rot ADI-AUC {summary.get('adi_auc_rot_top1', float('nan')):.1f} %, "
                  f"contact {summary.get('contact_acc_top1', float('nan')):.1f} %, "
                  f"{summary['time_s_median']:.2f} s per estimate", flush=True)
    results = {name: {f"L{L}": by_name[first_with[keys[name]]][f"L{L}"] for L in counts[name]} for name in names}
    write_json(layout.metrics_file(artifacts, f"ablation_{args.scene_set}"), results)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
