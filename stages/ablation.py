"""Stage ablation: the effect of each accuracy switch (normals, best_n, refinement) for L = 1, 2, 3 sensors.

Every variant of config section ``ablation.variants`` is merged over the ``select``, ``optimize`` and
``rank`` sections (method ``ours``, solver ``ablation.solver``), and each scene of the set is estimated
from every subset of 1, 2 and 3 of its sensors (``tactile6d.sensor_subsets``, as in sensor_study).
Reads the scenes and each object's artifacts; writes ``artifacts/metrics/ablation_<set>.json``: variant
-> ``L1``/``L2``/``L3`` -> the evaluation's metric names, plus ``time_s_median`` (per estimate).
"""

from __future__ import annotations

import sys

import numpy as np
from omegaconf import OmegaConf

from tactile6d import evaluation, layout
from tactile6d.config import parse_stage_args
from tactile6d.errors import ConfigError, exit_on_error
from tactile6d.estimator import Estimator
from tactile6d.io import read_artifact, write_json
from tactile6d.sensor_subsets import evaluate_sensor_count

SECTIONS = ("select", "optimize", "rank")


def variant_config(cfg, name: str, overrides):
    """The composed config with one variant's overrides (a mapping of select/optimize/rank keys) merged in."""
    overrides = OmegaConf.to_container(overrides) if overrides is not None else {}
    unknown = sorted(set(overrides) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"ablation.variants.{name} may override only {', '.join(SECTIONS)}, not {unknown}")
    base = {"select": {"method": "ours"}, "optimize": {"solver": str(cfg.ablation.solver)}}
    return OmegaConf.merge(cfg, base, overrides)


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    artifacts = cfg.paths.artifacts_dir
    scenes = read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes")
    objects = [str(o) for o in dict.fromkeys(scenes["objects"].tolist())]
    n_sensors = scenes["T_world_sensors"].shape[1] if len(objects) else 0
    references = {obj: evaluation.load_object_reference(artifacts, obj) for obj in objects}
    variants = {name: variant_config(cfg, name, v) for name, v in cfg.ablation.variants.items()}

    results = {}
    for name, variant_cfg in variants.items():
        estimators = {obj: Estimator.from_artifacts(obj, artifacts, variant_cfg) for obj in objects}
        results[name] = {}
        for L in range(1, n_sensors + 1):
            summary, seconds = evaluate_sensor_count(scenes, estimators, references, L, desc=f"{name} L={L}")
            summary["time_s_median"] = float(np.median(seconds)) if seconds else float("nan")
            results[name][f"L{L}"] = summary
            print(f"{args.scene_set} {name} L={L}: position {summary.get('pos_err_cm_top1', float('nan')):.2f} cm, "
                  f"rot ADI-AUC {summary.get('adi_auc_rot_top1', float('nan')):.1f} %, "
                  f"contact {summary.get('contact_acc_top1', float('nan')):.1f} %, "
                  f"{summary['time_s_median']:.2f} s", flush=True)
    write_json(layout.metrics_file(artifacts, f"ablation_{args.scene_set}"), results)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(main))
