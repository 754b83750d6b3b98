"""Stage sensor_study: accuracy against the number of sensors L = 1, 2, 3 (the paper's Fig. 5).

Each scene of the set is estimated again with every subset of its sensors of size L (3 singles, 3
pairs, the triple), by both methods, through the online estimator (the code the select/optimize/rank
stages call). Contact accuracy counts the sensors of the subset. Reads the scenes and each object's
artifacts and config sections ``select``, ``optimize``, ``rank``; writes
``artifacts/metrics/sensor_count_<set>.json`` and the plot data ``artifacts/plots/sensor_count_<set>.csv``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import OmegaConf

from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json, write_text
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.evaluation.sensor_subsets import evaluate_sensor_count
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed

METHODS = ("ours", "baseline")


PLOTTED = ("pos_err_cm_top1", "contact_acc_top1", "adi_auc_paper_top1")


def plot_table(results: dict, n_sensors: int) -> str:
    """CSV with one row per L and one column per method and metric (``ours_pos_err_cm_top1``, ...)."""
    columns = [f"{m}_{key}" for m in METHODS for key in PLOTTED]
    lines = [",".join(["L", *columns])]
    for L in range(1, n_sensors + 1):
        values = [results[m][f"L{L}"].get(key, float("nan")) for m in METHODS for key in PLOTTED]
        lines.append(",".join([str(L), *(f"{v:.4f}" for v in values)]))
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = cfg.paths.artifacts_dir
    scenes = read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes")
    objects = [str(o) for o in dict.fromkeys(scenes["objects"].tolist())]
    n_sensors = scenes["T_world_sensors"].shape[1] if len(scenes["names"]) else 0

    references = {obj: scoring.load_object_reference(artifacts, obj) for obj in objects}

    results = {}
    for method in METHODS:
        method_cfg = OmegaConf.merge(cfg, {"select": {"method": method}})
        estimators = {obj: Estimator.from_artifacts(obj, artifacts, method_cfg) for obj in objects}
        results[method] = {}
        for L in range(1, n_sensors + 1):
            summary, _ = evaluate_sensor_count(scenes, estimators, references, L, desc=f"{method} L={L}")
            results[method][f"L{L}"] = summary
            print(f"{args.scene_set} {method} L={L}: position {summary.get('pos_err_cm_top1', float('nan')):.2f} cm, "
                  f"contact {summary.get('contact_acc_top1', float('nan')):.1f} %")

    write_json(layout.metrics_file(artifacts, f"sensor_count_{args.scene_set}"), results)
    write_text(Path(artifacts) / "plots" / f"sensor_count_{args.scene_set}.csv", plot_table(results, n_sensors))
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
