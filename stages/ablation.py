"""Stage ablation: the effect of each accuracy switch (normals, best_n, refinement) for L = 1, 2, 3 sensors.

Every variant of config section ``ablation.variants`` is applied to the ``select``, ``optimize`` and
``rank`` sections (``tactile6d.variants``: method ``ours``; solver ``ablation.solver`` unless the variant
sets its own; a variant may start from a preset's sections), and each
scene of the set is estimated from every subset of 1, 2 and 3 of its sensors (``tactile6d.sensor_subsets``,
as in sensor_study). Variants run in ``ablation.workers`` processes; two variants that come out as the
same settings (e.g. the last step of the chain and ``default``) are estimated once. Reads the scenes and
each object's artifacts; writes ``artifacts/metrics/ablation_<set>.json``: variant -> ``L1``/``L2``/``L3``
-> the evaluation's metric names, plus ``time_s_median`` (per estimate).
"""

from __future__ import annotations

import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from omegaconf import OmegaConf

from tactile6d import evaluation, layout
from tactile6d.config import parse_stage_args
from tactile6d.errors import ConfigError, exit_on_error
from tactile6d.estimator import Estimator
from tactile6d.io import read_artifact, write_json
from tactile6d.optimize import use_cpu_devices
from tactile6d.sensor_subsets import evaluate_sensor_count
from tactile6d.variants import estimator_settings_key, variant_config


def evaluate_variant(cfg_container: dict, scene_set: str, name: str, progress: bool) -> dict[str, dict[str, float]]:
    """One variant: ``L1``, ``L2``, ... -> summary with ``time_s_median``. Reads its own inputs, so that
    it can run in a fresh worker process."""
    cfg = OmegaConf.create(cfg_container)
    artifacts = cfg.paths.artifacts_dir
    scenes = read_artifact(layout.scenes_file(artifacts, scene_set), "scenes")
    objects = [str(o) for o in dict.fromkeys(scenes["objects"].tolist())]
    n_sensors = scenes["T_world_sensors"].shape[1] if objects else 0
    references = {obj: evaluation.load_object_reference(artifacts, obj) for obj in objects}
    estimators = {obj: Estimator.from_artifacts(obj, artifacts, cfg) for obj in objects}
    out = {}
    for L in range(1, n_sensors + 1):
        summary, seconds = evaluate_sensor_count(scenes, estimators, references, L, f"{name} L={L}", progress)
        summary["time_s_median"] = float(np.median(seconds)) if seconds else float("nan")
        out[f"L{L}"] = summary
        print(f"{scene_set} {name} L={L}: position {summary.get('pos_err_cm_top1', float('nan')):.2f} cm, "
              f"rot ADI-AUC {summary.get('adi_auc_rot_top1', float('nan')):.1f} %, "
              f"contact {summary.get('contact_acc_top1', float('nan')):.1f} %, "
              f"{summary['time_s_median']:.2f} s per estimate", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    workers = int(cfg.ablation.workers)
    if workers < 1:
        raise ConfigError(f"ablation.workers must be >= 1, got {workers}")
    variants = {name: variant_config(cfg, name, v) for name, v in cfg.ablation.variants.items()}
    first_with = {}  # settings key -> the first variant that has those settings
    for name, variant_cfg in variants.items():
        first_with.setdefault(estimator_settings_key(variant_cfg), name)
    unique = list(first_with.values())

    jobs = [(OmegaConf.to_container(variants[n], resolve=True), args.scene_set, n) for n in unique]
    # JAX's device count is set once per process, before any variant runs (the paper's runs the gd solver).
    devices = (int(cfg.optimize.cpu_devices),)
    if workers == 1 or len(jobs) == 1:
        use_cpu_devices(*devices)
        computed = [evaluate_variant(*job, progress=True) for job in jobs]
    else:
        # spawn, not fork: the parent must not hand its HDF5 handles and torch threads to the workers
        with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=multiprocessing.get_context("spawn"),
                                 initializer=use_cpu_devices, initargs=devices) as pool:
            computed = list(pool.map(evaluate_variant, *zip(*jobs), [False] * len(jobs)))
    by_name = dict(zip(unique, computed))
    results = {name: by_name[first_with[estimator_settings_key(c)]] for name, c in variants.items()}
    write_json(layout.metrics_file(cfg.paths.artifacts_dir, f"ablation_{args.scene_set}"), results)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(main))
