"""Stage sensor_study: accuracy against the number of sensors L = 1, 2, 3 (the paper's Fig. 5).

Each scene of the set is estimated again with every subset of its sensors of size L (3 singles, 3
pairs, the triple), by both methods, through the online estimator (the code the select/optimize/rank
stages call). Contact accuracy counts the sensors of the subset. One task per method and scene
(``sensor_subsets.score_scene_task``), ``evaluate.workers`` local processes by default, a Dask cluster's
workers when ``executor.address`` names one; the rows come back in scene order, so the figures are the
same wherever the tasks ran. Reads the scenes and each object's artifacts and config sections ``select``,
``optimize``, ``rank``; writes
``artifacts/metrics/sensor_count_<set>.json`` and the plot data ``artifacts/plots/sensor_count_<set>.csv``.
"""

from __future__ import annotations

import sys
import uuid
from pathlib import Path

from omegaconf import OmegaConf

from tactile6d.core.config import config_for_workers
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json, write_text
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation.sensor_subsets import scene_task_input, score_scene_task, summarise_subset_rows
from tactile6d.runtime.executor import executor_from_config
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
    n_sensors = scenes["T_world_sensors"].shape[1] if len(scenes["names"]) else 0

    counts = tuple(range(1, n_sensors + 1))
    containers = {method: config_for_workers(OmegaConf.merge(cfg, {"select": {"method": method}})) for method in METHODS}
    jobs = [(method, s) for method in METHODS for s in range(len(scenes["names"]))]  # method-major: a worker keeps one library
    workers = int(cfg.evaluate.workers)
    if workers < 1:
        raise ConfigError(f"evaluate.workers must be >= 1, got {workers}")
    run = uuid.uuid4().hex
    with executor_from_config(cfg, workers, initializer=use_cpu_devices_for,
                              initargs=(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))) as ex:
        rows = ex.map(score_scene_task, [run] * len(jobs), [m for m, _ in jobs], [containers[m] for m, _ in jobs],
                      [scene_task_input(scenes, s) for _, s in jobs], [counts] * len(jobs),
                      desc=f"sensor study {args.scene_set}")
    by_job = dict(zip(jobs, rows))
    scene_objects = [str(o) for o in scenes["objects"]]

    results = {}
    for method in METHODS:
        results[method] = {}
        for L in counts:
            summary, _ = summarise_subset_rows([by_job[method, s][L] for s in range(len(scene_objects))], scene_objects)
            results[method][f"L{L}"] = summary
            print(f"{args.scene_set} {method} L={L}: position {summary.get('pos_err_cm_top1', float('nan')):.2f} cm, "
                  f"contact {summary.get('contact_acc_top1', float('nan')):.1f} %")

    write_json(layout.metrics_file(artifacts, f"sensor_count_{args.scene_set}"), results)
    write_text(Path(artifacts) / "plots" / f"sensor_count_{args.scene_set}.csv", plot_table(results, n_sensors))
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
