"""scripts/update_readme.py: the README's results block from reports/results.md, and its sentence on how
long `make reproduce` took from the run's own record (scripts/record_reproduce_time.py)."""

import datetime
from pathlib import Path

import pytest

from tactile6d.runtime import stage_clock
from script_loader import load_script

update_readme = load_script("update_readme")

PAGE = """Generated on a day.

### The paper's 40 triplets (test set), L = 3

| a | b |

### Per object (caddeo2023)

| c |

### Off-axis scenes (generated; sensors tilted and touching off the gel's centre)

![x](figures/x.png)

### Real set-ups: light that drifted, sensor poses off (generated)

| r |

### Confidence: can an estimate be trusted?

![reliability diagram](figures/reliability.png)

### Which object: identification over the library

| e |

### Your own objects: meshes tactile6d never saw (generated)

| o |

### Tracking: following the object over frames (generated sequences)

![tracking error over time](figures/tracking_error.png)

### Ablation: each switch, L = 1, 2, 3 sensors

| d |

### Stage times

| stage | seconds |
"""


def test_the_readme_gets_the_headline_sections_and_a_link_to_the_rest():
    body = update_readme.headline(PAGE)
    assert body.startswith("Generated on a day.")
    assert "| a | b |" in body and "](reports/figures/x.png)" in body and "| e |" in body and "| r |" in body
    assert "](reports/figures/reliability.png)" in body and "| o |" in body
    assert "](reports/figures/tracking_error.png)" in body
    assert "| c |" not in body and "| d |" not in body and "| stage | seconds |" not in body
    assert "on [reports/results.md](reports/results.md): Per object, Ablation, Stage times." in body
    assert body.index("The paper's 40") < body.index("Off-axis")


def test_a_page_without_a_headline_section_is_an_error():
    with pytest.raises(ValueError, match="lacks the sections"):
        update_readme.headline(PAGE.replace("### Per object (caddeo2023)", "").replace("### Off-axis", "### Other"))


record_reproduce_time = load_script("record_reproduce_time")

README = """# project

<!-- reproduce-time:start -->
It took an unknown time.
<!-- reproduce-time:end -->

`make test` took a while.

<!-- results:start -->
old results
<!-- results:end -->

The rest.
"""


def stage_records(start: float, before: int, during: list[float]) -> list[dict]:
    """Time records of ``before`` stages that ran an hour before ``start`` (epoch seconds) and of the ``during``
    seconds of stages run one after another from 5 s after it (the install, DVC's start-up)."""
    t = datetime.datetime.fromtimestamp(start).astimezone()
    old = [stage_clock.record(f"old@{i}", 10.0, t - datetime.timedelta(hours=1)) for i in range(before)]
    ends = [5 + sum(during[:i + 1]) for i in range(len(during))]
    new = [stage_clock.record(f"new@{i}", s, t + datetime.timedelta(seconds=e)) for i, (s, e) in enumerate(zip(during, ends))]
    return old + new


def write_tree(root: Path, rec: dict | None) -> None:
    (root / "reports").mkdir()
    (root / "reports" / "results.md").write_text(PAGE)
    (root / "README.md").write_text(README)
    if rec is not None:
        stage_clock.write_record(root / "artifacts" / "times" / "make_reproduce.json", rec)


def test_the_readme_gets_the_time_make_reproduce_recorded(tmp_path):
    start = 1_795_000_000.0
    rec = record_reproduce_time.reproduce_record(start, start + 3011.4, stage_records(start, 0, [30.0, 2000.0, 900.0]),
                                                 installed=True, local_data=True)
    assert (rec["stages"], rec["stages_run"], rec["stages_run_seconds"]) == (3, 3, 2930.0)
    write_tree(tmp_path, rec)
    assert update_readme.main(tmp_path) == 0
    text = (tmp_path / "README.md").read_text()
    sentence = text.split("<!-- reproduce-time:start -->\n")[1].split("\n<!-- reproduce-time:end -->")[0]
    assert sentence.startswith("The last `make reproduce` took **50 min 11 s** here")
    assert "DVC ran all 3 stages, 48 min 50 s of stage time together" in sentence
    assert "venv creation and install included" in sentence and "local copy" in sentence
    assert "unknown time" not in text and "| a | b |" in text and "old results" not in text
    assert text.endswith("<!-- results:end -->\n\nThe rest.\n") and "`make test` took a while." in text


def test_a_partial_run_says_how_many_stages_dvc_ran():
    start = 1_795_000_000.0
    rec = record_reproduce_time.reproduce_record(start, start + 100, stage_records(start, 4, [70.0]),
                                                 installed=False, local_data=False)
    sentence = update_readme.reproduce_sentence(rec)
    assert "DVC ran 1 of the pipeline's 5 stages" in sentence and "1 min 10 s of stage time" in sentence
    assert "the venv was already installed" in sentence and "pinned download" in sentence


def test_without_a_recorded_time_the_sentence_stays(tmp_path):
    write_tree(tmp_path, None)
    assert update_readme.main(tmp_path) == 0
    text = (tmp_path / "README.md").read_text()
    assert "It took an unknown time." in text and "| a | b |" in text
