"""Stage evaluate: both methods' metrics on one scene set (docs/design.md, The metrics; the paper's Table I).

Reads ``artifacts/scenes/<set>.h5``, ``artifacts/runs/<set>/{ours,baseline}/ranked.h5``, the objects'
meshes, metric points and surface points, the confidence model (``artifacts/confidence/model.json``,
stage calibrate_confidence: how well ours' confidence tells right from wrong on this set), and the
``evaluate`` config section (the image-consistent contact metric's
ray-grid step and IoU threshold). Writes ``artifacts/metrics/<set>.json`` (DVC metrics: method -> metric,
averages over objects), ``artifacts/eval/<set>.json`` (per object and per scene) and
``artifacts/eval/<set>_table.md`` (Table I layout).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json, write_text
from tactile6d.data.object_artifacts import load_surface_points
from tactile6d.estimation import confidence
from tactile6d.evaluation import scoring
from tactile6d.evaluation.metric_table import ERROR_KEYS, HEADLINE_KEYS
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim import gel_press
from tactile6d.sim.render import mesh_arrays

METHODS = ("ours", "baseline")
STEPS = ("encode", "select", "optimize", "rank")


def method_errors(ranked, scenes, objects_data, meshes, k: int, image_step: int,
                  image_iou_min: float) -> dict[str, np.ndarray]:
    """Per-scene (S, k) error arrays of one method's ranked poses: ``scoring.scene_errors`` and
    ``contact_image_ok`` (1.0 / 0.0, NaN where there is no estimate): ``gel_press.image_consistency`` on
    a ray grid of ``image_step`` pixels with the IoU threshold ``image_iou_min``. meshes: object name ->
    ``render.MeshArrays``."""
    names = scenes["names"].tolist()
    if ranked["names"].tolist() != names:
        raise ValueError("ranked poses and scenes list different scenes: re-run the pipeline")
    rows = {key: [] for key in (*ERROR_KEYS, "contact_image_ok")}
    for s in tqdm(range(len(names)), desc="evaluate", unit="scene", leave=False):
        obj = str(scenes["objects"][s])
        ref = objects_data[obj]
        n = min(int(ranked["n_poses"][s]), k)
        e = scoring.scene_errors(ranked["poses"][s], n, scenes["T_world_object"][s],
                                    scenes["T_world_sensors"][s], ref.points, ref.surface, tree=ref.tree, k=k)
        image = gel_press.image_consistency(meshes[obj], ranked["poses"][s][:n], scenes["T_world_object"][s],
                                              scenes["T_world_sensors"][s], step=image_step, iou_min=image_iou_min)
        e["contact_image_ok"] = scoring.pad_to_k(image["consistent"], k)
        for key, values in rows.items():
            values.append(e[key])
    return {key: np.array(value).reshape(len(names), k) for key, value in rows.items()}


def scenes_with_untouched_sensors(scenes, meshes, image_step: int) -> list[str]:
    """Names of the scenes in which the true pose leaves some sensor's gel unpressed on the ray grid."""
    out = []
    for s, name in enumerate(scenes["names"].tolist()):
        depth = gel_press.poses_to_gel_depths(meshes[str(scenes["objects"][s])], scenes["T_world_object"][s],
                                                scenes["T_world_sensors"][s], image_step)
        if np.any(gel_press.empty_true_masks(depth[0] > 0)):
            out.append(name)
    return out


def timing_summary(ranked) -> dict[str, float]:
    """Median seconds per estimate, total and by step."""
    per_step = {step: np.asarray(ranked[f"seconds_{step}"], dtype=float) for step in STEPS}
    total = sum(per_step.values())
    ok = np.asarray(ranked["n_poses"]) > 0
    out = {"time_s_median": float(np.median(total[ok])) if ok.any() else float("nan")}
    out.update({f"time_s_{step}_median": float(np.median(v[ok])) if ok.any() else float("nan")
                for step, v in per_step.items()})
    return out


def confidence_summary(ranked, adi_best: np.ndarray, model: confidence.ConfidenceModel,
                       artifacts) -> tuple[dict, list[dict], list[float]]:
    """How the confidence of each ranked scene tells "ADI of #1 < 1 cm" from not: headline metrics
    (AUROC, Brier score, mean confidence, flagged ambiguous) and the per-scene probabilities (NaN where
    nothing was ranked). adi_best (S,) m."""
    points = {o: confidence.spread_points(load_surface_points(artifacts, o)) for o in set(ranked["objects"].tolist())}
    p, n_distinct = np.full(len(adi_best), np.nan), np.zeros(len(adi_best), dtype=np.int64)
    for s, obj in enumerate(ranked["objects"].tolist()):
        n = int(ranked["n_poses"][s])
        if n:
            p[s], distinct = confidence.assess(model, points[obj], ranked["poses"][s][:n], ranked["scores"][s][:n])
            n_distinct[s] = len(distinct)
    ok = ~np.isnan(p)
    success = adi_best[ok] < confidence.SUCCESS_ADI
    return {"confidence_auroc_adi1cm": confidence.auroc(p[ok], success),
            "confidence_brier": confidence.brier(p[ok], success),
            "confidence_mean": float(np.mean(p[ok])),
            "ambiguous_fraction": float(np.mean(n_distinct[ok] > 1)),
            "n_wrong_adi1cm": int((~success).sum())}, confidence.reliability(p[ok], success), p.tolist()


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    artifacts = cfg.paths.artifacts_dir
    scenes = read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes")
    objects = [str(o) for o in dict.fromkeys(scenes["objects"].tolist())]
    objects_data = {obj: scoring.load_object_reference(artifacts, obj) for obj in objects}
    meshes = {obj: mesh_arrays(ref.surface.mesh) for obj, ref in objects_data.items()}
    k = scoring.TOP_K
    image_step, image_iou_min = int(cfg.evaluate.contact_image_step), float(cfg.evaluate.contact_image_iou_min)
    untouched = scenes_with_untouched_sensors(scenes, meshes, image_step)
    if untouched:
        # The scene sets press every sensor into the object, so this marks a broken scene. It is kept; such
        # a sensor agrees with an estimate only when the estimate leaves it untouched too (gel_contact).
        warnings.warn(f"{args.scene_set}: {len(untouched)} scene(s) with a sensor that the true pose does not "
                      f"press, e.g. {', '.join(untouched[:5])}", stacklevel=1)

    model = confidence.ConfidenceModel.from_json(layout.confidence_model_file(artifacts).read_text())
    summary, details, headline = {}, {}, {}
    for method in METHODS:
        ranked = read_artifact(layout.run_dir(artifacts, args.scene_set, method) / "ranked.h5", "ranked")
        errors = method_errors(ranked, scenes, objects_data, meshes, k, image_step, image_iou_min)
        by_object = scoring.summarise_by_object(errors, scenes["objects"])
        summary[method] = by_object
        headline[method] = {**by_object.get("average", {}), **timing_summary(ranked), "n_scenes": len(scenes["names"]),
                            "n_failed": int((np.asarray(ranked["n_poses"]) == 0).sum())}
        details[method] = {
            "per_object": by_object,
            "per_scene": {name: {key: errors[key][s].tolist() for key in errors}
                          for s, name in enumerate(scenes["names"].tolist())},
            "failure": dict(zip(scenes["names"].tolist(), ranked["failure"].tolist())),
        }
        if method == "ours":  # the confidence is fitted on ours' estimates
            figures, bins, probabilities = confidence_summary(ranked, errors["adi"][:, 0], model, artifacts)
            headline[method].update(figures)
            details[method]["confidence"] = {"reliability": bins,
                                             "per_scene": dict(zip(scenes["names"].tolist(), probabilities))}
        print(f"{args.scene_set}/{method}: " + ", ".join(
            f"{key} {headline[method].get(key, float('nan')):.2f}"
            for key in (*HEADLINE_KEYS, "contact_acc_top1", "contact_acc_image_top1", "confidence_auroc_adi1cm",
                        "time_s_median")))

    write_json(layout.metrics_file(artifacts, args.scene_set), headline)
    eval_dir = Path(artifacts) / "eval"
    write_json(eval_dir / f"{args.scene_set}.json", details)
    table = scoring.table_markdown(summary, METHODS) if objects else "(no scenes)"
    write_text(eval_dir / f"{args.scene_set}_table.md", table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
