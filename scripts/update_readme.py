"""Copy the headline of the generated results page (reports/results.md, stage report) into README.md
between the markers ``<!-- results:start -->`` and ``<!-- results:end -->``, rewriting its figure links,
and the time the last `make reproduce` took (artifacts/times/make_reproduce.json, which the Makefile
writes through scripts/record_reproduce_time.py) between ``<!-- reproduce-time:start -->`` and
``<!-- reproduce-time:end -->``. Run by `make reproduce`; without that time file (a `dvc repro` run by
hand) the time sentence is left as it is.

The headline is the page's first line (when and where it was generated) and the sections named in
``HEADLINE`` (the test set, off-axis, the real set-ups, the confidence, identification, your own objects,
tracking); the other sections (per object, validation, sensor count, ablation, autoencoder, scenes, the
time of each stage of the run) stay on reports/results.md, which the README links to, so that the README
stays short.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # this checkout's tactile6d

from tactile6d.runtime.stage_clock import duration  # noqa: E402

START, END = "<!-- results:start -->", "<!-- results:end -->"
TIME_START, TIME_END = "<!-- reproduce-time:start -->", "<!-- reproduce-time:end -->"
# Section headings (without "### ") copied into the README, in the page's order.
HEADLINE = ("The paper's 40 triplets (test set), L = 3",
            "Off-axis scenes (generated; sensors tilted and touching off the gel's centre)",
            "Real set-ups: light that drifted, sensor poses off (generated)",
            "Confidence: can an estimate be trusted?",
            "Which object: identification over the library",
            "Your own objects: meshes tactile6d never saw (generated)",
            "Tracking: following the object over frames (generated sequences)")


def split_sections(page: str) -> tuple[str, dict[str, str]]:
    """A results page -> (its text before the first ``### `` heading, {heading: section text with it})."""
    head, *parts = page.split("\n### ")
    sections = {}
    for part in parts:
        title = part.split("\n", 1)[0].strip()
        sections[title] = "### " + part.rstrip() + "\n"
    return head.rstrip() + "\n", sections


def headline(page: str, titles=HEADLINE) -> str:
    """The README's results block from a results page: its preamble, the ``titles`` sections, a link to the rest."""
    head, sections = split_sections(page)
    missing = [t for t in titles if t not in sections]
    if missing:
        raise ValueError(f"reports/results.md lacks the sections {missing}")
    rest = [re.split(r"[(:]", t)[0].strip() for t in sections if t not in titles]
    link = (f"Generated with these, on [reports/results.md](reports/results.md): {', '.join(rest)}.\n"
            if rest else "")
    body = "\n".join([head, *(sections[t] for t in titles), link])
    return body.replace("](figures/", "](reports/figures/")


def reproduce_sentence(rec: dict) -> str:
    """The README's sentence on how long `make reproduce` took, from its record (scripts/record_reproduce_time.py)."""
    setup = "venv creation and install included" if rec["installed"] else "the venv was already installed"
    data = "the data from a local copy (`DATA=`)" if rec["local_data"] else "the data from the pinned download"
    if rec["stages_run"] == rec["stages"]:
        ran = f"DVC ran all {rec['stages']} stages"
    else:
        ran = (f"DVC ran {rec['stages_run']} of the pipeline's {rec['stages']} stages (the others were unchanged "
               "or restored from its run cache)")
    return (f"The last `make reproduce` took **{duration(rec['seconds'])}** here, ending on {rec['finished'][:10]} "
            f"({rec['cpu']}, {rec['cores']} cores; {setup}; {data}). In it {ran}, "
            f"{duration(rec['stages_run_seconds'])} of stage time together; each stage's time: "
            "[reports/results.md](reports/results.md#stage-times). Measured by the run itself "
            "(artifacts/times/, docs/pipeline.md).")


def replace_between(text: str, start: str, end: str, body: str) -> str:
    """``text`` with what lies between the markers ``start`` and ``end`` (on their own lines) replaced by ``body``."""
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{start}\n{body}\n{end}{tail}"


def main(root: Path | None = None) -> int:
    """Update ``root``/README.md (default: this checkout's) from its results page and reproduction time."""
    root = root or Path(__file__).resolve().parent.parent
    results = root / "reports" / "results.md"
    readme = root / "README.md"
    reproduce_time = root / "artifacts" / "times" / "make_reproduce.json"
    if not results.is_file():
        print(f"{results} not found: run `dvc repro report` first", file=sys.stderr)
        return 1
    text = readme.read_text()
    for start, end in ((START, END), (TIME_START, TIME_END)):
        if start not in text or end not in text:
            print(f"README.md lacks the markers {start} / {end}", file=sys.stderr)
            return 1
    try:
        body = headline(results.read_text())
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 1
    text = replace_between(text, START, END, body)
    if reproduce_time.is_file():
        text = replace_between(text, TIME_START, TIME_END, reproduce_sentence(json.loads(reproduce_time.read_text())))
        print("README.md: reproduction time updated from artifacts/times/make_reproduce.json")
    else:
        print(f"README.md: reproduction time left as it was (no {reproduce_time.relative_to(root)})")
    readme.write_text(text)
    print("README.md: results section updated from reports/results.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
