"""Every figure the evaluation reports, in one table: its key (as in artifacts/metrics/*.json), its label in
the reports, tactile6d's target on the paper's test set and the paper's own value (Table I).

The definitions of the errors are in ``core.metrics`` (per estimate) and ``evaluation.scoring`` (their
pooling over scenes and objects); docs/design.md, The metrics, says why each target is what it is.
"""

from __future__ import annotations

from dataclasses import dataclass

# The per-scene errors of the k best poses (``scoring.scene_errors``): positional error (m), ADI (m),
# rotation-only ADI (m), classifier contact accuracy (bool).
ERROR_KEYS = ("position", "adi", "adi_rotation", "contact_ok")

# The summaries' keys (``scoring.summarise``; percentages 0-100 except where the name says cm).
SUMMARY_KEYS = (
    "pos_err_cm_top1", "pos_err_cm_top5",
    "adi_auc_paper_top1", "adi_auc_paper_top5",
    "adi_auc_std_top1", "adi_auc_std_top5",
    "adi_auc_rot_top1", "adi_auc_rot_top5",
    "contact_acc_top1", "contact_acc_top5",
    "contact_acc_image_top1", "contact_acc_image_top5",
)


@dataclass(frozen=True)
class Metric:
    """One reported figure: ``target`` (comparison, value) on the test set, caddeo2023, ours at L = 3 (as
    raised on 2026-11-22), and the paper's Table I values for its method and its baseline; None where
    there is none."""

    key: str
    label: str
    target: tuple[str, float] | None = None
    paper_ours: float | None = None
    paper_baseline: float | None = None


# In the order of the reports' tables.
METRICS = (
    Metric("pos_err_cm_top1", "positional error #1 (cm)", ("<", 1.5), 2.36, 4.76),
    Metric("pos_err_cm_top1_median", "positional error #1, median over scenes (cm)"),
    Metric("pos_err_cm_top5", "positional error #1-5 (cm)"),
    Metric("adi_auc_paper_top1", "ADI-AUC #1 (%, paper's VOCap)", (">", 90.0), 70.8, 40.3),
    Metric("adi_auc_std_top1", "ADI-AUC #1 (%, standard)"),
    Metric("adi_auc_rot_top1", "rotation ADI-AUC #1 (%)", (">", 95.0), 81.3),
    Metric("contact_acc_top1", "contact accuracy #1 (%, classifier)", (">", 87.5), 87.5, 25.0),
    Metric("contact_acc_image_top1", "contact accuracy #1 (%, image-consistent)", (">", 90.0)),
    Metric("time_s_median", "time per estimate (s, median)", ("<=", 0.5), 35.7, 71.9),
)
LABELS = {m.key: m.label for m in METRICS}
TARGETS = {m.key: m.target for m in METRICS if m.target is not None}
# The headline figures of a method on a scene set, as the evaluate stage logs them and identification reports them.
HEADLINE_KEYS = ("pos_err_cm_top1", "adi_auc_paper_top1", "adi_auc_rot_top1")
