"""Stage evaluate: the metrics of DESIGN §6 for both methods on one scene set (the paper's Table I).

Reads ``artifacts/scenes/<set>.h5``, ``artifacts/runs/<set>/{ours,baseline}/ranked.h5`` and the objects'
meshes and metric points. Writes ``artifacts/metrics/<set>.json`` (DVC metrics: method -> metric,
averages over objects), ``artifacts/eval/<set>.json`` (per object and per scene) and
``artifacts/eval/<set>_table.md`` (Table I layout).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tactile6d import evaluation, layout
from tactile6d.config import parse_stage_args
from tactile6d.errors import exit_on_error
from tactile6d.io import read_artifact, write_json, write_text

METHODS = ("ours", "baseline")
STEPS = ("encode", "select", "optimize", "rank")


def method_errors(ranked, scenes, objects_data, k: int) -> dict[str, np.ndarray]:
    """Per-scene (S, k) error arrays of one method's ranked poses."""
    names = scenes["names"].tolist()
    if ranked["names"].tolist() != names:
        raise ValueError("ranked poses and scenes list different scenes: re-run the pipeline")
    rows = {key: [] for key in ("position", "adi", "adi_rotation", "contact_ok")}
    for s in tqdm(range(len(names)), desc="evaluate", unit="scene", leave=False):
        ref = objects_data[str(scenes["objects"][s])]
        e = evaluation.scene_errors(ranked["poses"][s], int(ranked["n_poses"][s]), scenes["T_world_object"][s],
                                    scenes["T_world_sensors"][s], ref.points, ref.surface, tree=ref.tree, k=k)
        for key in rows:
            rows[key].append(e[key])
    return {key: np.array(value).reshape(len(names), k) for key, value in rows.items()}


def timing_summary(ranked) -> dict[str, float]:
    """Median seconds per estimate, total and by step."""
    per_step = {step: np.asarray(ranked[f"seconds_{step}"], dtype=float) for step in STEPS}
    total = sum(per_step.values())
    ok = np.asarray(ranked["n_poses"]) > 0
    out = {"time_s_median": float(np.median(total[ok])) if ok.any() else float("nan")}
    out.update({f"time_s_{step}_median": float(np.median(v[ok])) if ok.any() else float("nan")
                for step, v in per_step.items()})
    return out


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    artifacts = cfg.paths.artifacts_dir
    scenes = read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes")
    objects = [str(o) for o in dict.fromkeys(scenes["objects"].tolist())]
    objects_data = {obj: evaluation.load_object_reference(artifacts, obj) for obj in objects}
    k = evaluation.TOP_K

    summary, details, headline = {}, {}, {}
    for method in METHODS:
        ranked = read_artifact(layout.run_dir(artifacts, args.scene_set, method) / "ranked.h5", "ranked")
        errors = method_errors(ranked, scenes, objects_data, k)
        by_object = evaluation.summarise_by_object(errors, scenes["objects"])
        summary[method] = by_object
        headline[method] = {**by_object.get("average", {}), **timing_summary(ranked), "n_scenes": len(scenes["names"]),
                            "n_failed": int((np.asarray(ranked["n_poses"]) == 0).sum())}
        details[method] = {
            "per_object": by_object,
            "per_scene": {name: {key: errors[key][s].tolist() for key in errors}
                          for s, name in enumerate(scenes["names"].tolist())},
            "failure": dict(zip(scenes["names"].tolist(), ranked["failure"].tolist())),
        }
        print(f"{args.scene_set}/{method}: " + ", ".join(
            f"{key} {headline[method].get(key, float('nan')):.2f}"
            for key in ("pos_err_cm_top1", "adi_auc_paper_top1", "adi_auc_rot_top1", "contact_acc_top1",
                        "time_s_median")))

    write_json(layout.metrics_file(artifacts, args.scene_set), headline)
    eval_dir = Path(artifacts) / "eval"
    write_json(eval_dir / f"{args.scene_set}.json", details)
    table = evaluation.table_markdown(summary, METHODS) if objects else "(no scenes)"
    write_text(eval_dir / f"{args.scene_set}_table.md", table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(main))
