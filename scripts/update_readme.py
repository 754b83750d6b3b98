"""Copy the generated results page (reports/results.md, stage report) into README.md between the markers
``<!-- results:start -->`` and ``<!-- results:end -->``, rewriting its figure links. Run by `make reproduce`."""

from __future__ import annotations

import sys
from pathlib import Path

START, END = "<!-- results:start -->", "<!-- results:end -->"


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
    body = results.read_text().replace("](figures/", "](reports/figures/")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    readme.write_text(f"{head}{START}\n{body}\n{END}{tail}")
    print("README.md: results section updated from reports/results.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
