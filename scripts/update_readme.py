"""Copy the headline of the generated results page (reports/results.md, stage report) into README.md
between the markers ``<!-- results:start -->`` and ``<!-- results:end -->``, rewriting its figure links.
Run by `make reproduce`.

The headline is the page's first line (when and where it was generated) and the sections named in
``HEADLINE``; the other sections (per object, validation, sensor count, ablation, autoencoder, scenes)
stay on reports/results.md, which the README links to, so that the README stays short.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

START, END = "<!-- results:start -->", "<!-- results:end -->"
# Section headings (without "### ") copied into the README, in the page's order.
HEADLINE = ("The paper's 40 triplets (test set), L = 3",
            "Off-axis scenes (generated; sensors tilted and touching off the gel's centre)",
            "Which object: identification over the library")


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


def main() -> int:
    root = Path(__file__).resolve().parent.parent
    results = root / "reports" / "results.md"
    readme = root / "README.md"
    if not results.is_file():
        print(f"{results} not found: run `dvc repro report` first", file=sys.stderr)
        return 1
    text = readme.read_text()
    if START not in text or END not in text:
        print(f"README.md lacks the markers {START} / {END}", file=sys.stderr)
        return 1
    try:
        body = headline(results.read_text())
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 1
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    readme.write_text(f"{head}{START}\n{body}\n{END}{tail}")
    print("README.md: results section updated from reports/results.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
