"""From ranked estimates to the paper's Table I: per-scene errors, then per-object and average summaries.

The pooling follows the paper's results script: for each object, positional errors are averaged over
its scenes (#1: the best pose of each scene; #1-5: the mean over each scene's five best); ADI-AUC pools
the ADIs of the object's scenes (#1: one per scene; #1-5: the five best of every scene together);
contact accuracy is the share of estimates whose every sensor touches the right kind of surface;
image-consistent contact accuracy (``tactile6d.sim.gel_press``, computed by the evaluate stage, which
adds it to the errors as ``contact_image_ok``) the share whose every sensor's predicted contact mask
overlaps the one at the true pose.
The average row is the mean of the per-object figures.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from tactile6d.core import metrics
from tactile6d.data.object_artifacts import load_mesh, load_metric_points
from tactile6d.evaluation import contact_accuracy
from tactile6d.evaluation.metric_table import ERROR_KEYS, SUMMARY_KEYS
from tactile6d.sim import surface_sampling

TOP_K = 5


@dataclass
class ObjectReference:
    """What the metrics need of one object: its metric points (N, 3), a tree over them, its surface."""

    points: np.ndarray
    tree: object
    surface: surface_sampling.SurfaceSamples


def load_object_reference(artifacts_dir, name: str) -> ObjectReference:
    """The reference of a prepared object (``artifacts/objects/<name>.h5``, stage prepare_object)."""
    points = load_metric_points(artifacts_dir, name)
    return ObjectReference(points, metrics.model_tree(points), surface_sampling.sample_surface(load_mesh(artifacts_dir, name)))


def scene_errors(
    ranked_poses: np.ndarray,
    n_ranked: int,
    T_gt: np.ndarray,
    T_world_sensors: np.ndarray,
    model_points: np.ndarray,
    surface: surface_sampling.SurfaceSamples,
    tree=None,
    k: int = TOP_K,
) -> dict[str, np.ndarray]:
    """Errors of one scene's k best estimates.

    ranked_poses (K, 4, 4) best first, of which the first ``n_ranked`` are real (ranking may return
    fewer distinct poses than K); T_gt (4, 4); T_world_sensors (L, 4, 4). Returns arrays of shape
    (k,), NaN where there is no estimate: ``position`` (m), ``adi`` (m), ``adi_rotation`` (m),
    ``contact_ok`` (1.0 / 0.0).
    """
    out = {key: np.full(k, np.nan) for key in ERROR_KEYS}
    n = min(int(n_ranked), k)
    if n == 0:
        return out
    T = np.asarray(ranked_poses)[:n]
    errors = metrics.ranked_pose_errors(model_points, T, T_gt, k=n, tree=tree)
    out["position"][:n] = errors["position"]
    out["adi"][:n] = errors["adi"]
    out["adi_rotation"][:n] = errors["adi_rotation"]
    out["contact_ok"][:n] = contact_accuracy.contact_accuracy(surface, T, T_gt, T_world_sensors)["correct"]
    return out


def pad_to_k(values: np.ndarray, k: int = TOP_K) -> np.ndarray:
    """Per-estimate values (n,) of a scene's n <= k best estimates -> (k,) float, NaN where there is no
    estimate (the layout of ``scene_errors``' arrays)."""
    values = np.asarray(values, dtype=np.float64).ravel()[:k]
    out = np.full(k, np.nan)
    out[: len(values)] = values
    return out


def _auc(values: np.ndarray, variant: str) -> float:
    """ADI-AUC (percent) of pooled ADIs; a missing estimate counts as a failure (infinite ADI)."""
    d = np.where(np.isnan(values), np.inf, values).ravel()
    return 100.0 * metrics.adi_auc(d, variant)


def summarise(errors: dict[str, np.ndarray]) -> dict[str, float]:
    """Table I figures of one group of scenes: errors holds (S, k) arrays from ``scene_errors``.

    A scene without estimates counts as a failure in the AUCs and contact accuracies, and is left out
    of the positional error (which has no value for it). The image-consistent contact accuracy
    (``contact_acc_image_*``) is there when errors hold ``contact_image_ok`` (S, k) (1.0 / 0.0 / NaN),
    and is pooled like ``contact_ok``.
    """
    pos, adi, rot, ok = (np.asarray(errors[key]) for key in ERROR_KEYS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # nanmean of a scene without estimates
        out = {
            "pos_err_cm_top1": float(100.0 * np.nanmean(pos[:, 0])),
            "pos_err_cm_top5": float(100.0 * np.nanmean(np.nanmean(pos, axis=1))),
            "adi_auc_paper_top1": _auc(adi[:, 0], "paper"),
            "adi_auc_paper_top5": _auc(adi, "paper"),
            "adi_auc_std_top1": _auc(adi[:, 0], "standard"),
            "adi_auc_std_top5": _auc(adi, "standard"),
            "adi_auc_rot_top1": _auc(rot[:, 0], "paper"),
            "adi_auc_rot_top5": _auc(rot, "paper"),
            "contact_acc_top1": float(100.0 * np.mean(np.nan_to_num(ok[:, 0]))),
            "contact_acc_top5": float(100.0 * np.mean(np.nan_to_num(ok))),
        }
    if "contact_image_ok" in errors:
        image_ok = np.asarray(errors["contact_image_ok"])
        out["contact_acc_image_top1"] = float(100.0 * np.mean(np.nan_to_num(image_ok[:, 0])))
        out["contact_acc_image_top5"] = float(100.0 * np.mean(np.nan_to_num(image_ok)))
    return out


def summarise_by_object(errors: dict[str, np.ndarray], objects: np.ndarray) -> dict[str, dict[str, float]]:
    """``summarise`` per object, plus ``"average"``: the mean over objects of each figure (the keys of
    ``SUMMARY_KEYS`` that ``summarise`` gives), and ``pos_err_cm_top1_median``, the median over all scenes
    of the best pose's positional error."""
    objects = np.asarray(objects)
    per_object = {
        str(obj): summarise({key: value[objects == obj] for key, value in errors.items()})
        for obj in dict.fromkeys(objects.tolist())
    }
    if per_object:
        per_object["average"] = {
            key: float(np.nanmean([row[key] for row in per_object.values()]))
            for key in SUMMARY_KEYS if all(key in row for row in per_object.values())
        }
        # The median over every scene (not per object): a few scenes far off move the mean, not it.
        top1 = np.asarray(errors["position"])[:, 0]
        if np.isfinite(top1).any():
            per_object["average"]["pos_err_cm_top1_median"] = float(100.0 * np.nanmedian(top1))
    return per_object


def table_markdown(summary: dict[str, dict[str, dict[str, float]]], methods=("ours", "baseline")) -> str:
    """A Markdown table in the layout of the paper's Table I: one row per object (and the average),
    for each method the positional error (cm) and ADI-AUC (%) for #1 and #1-5, rotation ADI-AUC and
    contact accuracy for #1."""
    header = ["object"]
    for m in methods:
        header += [f"{m} pos #1 (cm)", f"{m} pos #1-5 (cm)", f"{m} ADI-AUC #1", f"{m} ADI-AUC #1-5",
                   f"{m} rot ADI-AUC #1", f"{m} contact #1"]
    rows = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    objects = [o for o in summary[methods[0]] if o != "average"] + ["average"]
    for obj in objects:
        cells = [f"**{obj}**" if obj == "average" else obj]
        for m in methods:
            r = summary[m].get(obj, {})
            cells += [f"{r.get('pos_err_cm_top1', float('nan')):.2f}", f"{r.get('pos_err_cm_top5', float('nan')):.2f}",
                      f"{r.get('adi_auc_paper_top1', float('nan')):.1f}", f"{r.get('adi_auc_paper_top5', float('nan')):.1f}",
                      f"{r.get('adi_auc_rot_top1', float('nan')):.1f}", f"{r.get('contact_acc_top1', float('nan')):.1f}"]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def ablation_markdown(results: dict[str, dict[str, dict[str, float]]]) -> str:
    """A Markdown table of an ablation (variant -> ``L1``/``L2``/... -> summary): one row per variant, for
    each sensor count the positional error #1 (cm), rotation ADI-AUC #1, contact accuracy #1 (%) and the
    median seconds per estimate."""
    counts = sorted({L for row in results.values() for L in row}, key=lambda L: int(L[1:]))
    header = ["variant"] + [f"{L} {what}" for L in counts for what in ("pos (cm)", "rot AUC", "contact", "s")]
    rows = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for variant, by_count in results.items():
        cells = [variant]
        for L in counts:
            r = by_count.get(L, {})
            cells += [f"{r.get('pos_err_cm_top1', float('nan')):.2f}", f"{r.get('adi_auc_rot_top1', float('nan')):.1f}",
                      f"{r.get('contact_acc_top1', float('nan')):.1f}", f"{r.get('time_s_median', float('nan')):.2f}"]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)
