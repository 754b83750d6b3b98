"""The report stage's headline table: targets judged as stated, the paper's method as re-run here beside
the paper's own Table I."""

from stages import report


def row(table: str, label: str) -> list[str]:
    line = next(line for line in table.splitlines() if line.startswith(f"| {label} |"))
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_headline_table_judges_targets_and_shows_the_rerun_column():
    metrics = {"ours": {"pos_err_cm_top1": 1.2, "adi_auc_paper_top1": 89.9, "time_s_median": 0.5},
               "baseline": {"pos_err_cm_top1": 3.0}}
    rerun = {"pos_err_cm_top1": 2.35, "adi_auc_paper_top1": 84.1}
    table = report.headline_table(metrics, rerun=rerun)
    position = row(table, report.LABELS["pos_err_cm_top1"])
    assert position[1:4] == ["1.20", "3.00", "2.35"] and position[4] == "2.36" and position[-1] == "yes"
    assert row(table, report.LABELS["adi_auc_paper_top1"])[-1] == "**no**"  # 89.9 is not > 90
    assert row(table, report.LABELS["time_s_median"])[-1] == "yes"  # at most 0.5 s: 0.5 meets it
    image = row(table, report.LABELS["contact_acc_image_top1"])
    assert image[1] == "-" and image[-1] == ""  # not measured: neither met nor missed


def test_validation_table_has_no_paper_columns():
    table = report.headline_table({"ours": {"pos_err_cm_top1": 1.0}}, with_paper=False)
    assert "Table I" not in table and row(table, report.LABELS["pos_err_cm_top1"])[1:] == ["1.00", "-"]
