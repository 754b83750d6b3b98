"""Write tests/durations.json, each test file's measured seconds, from a JUnit XML report of the whole suite.

    pytest -q -n 2 --dist loadfile --junitxml=/tmp/junit.xml && python scripts/test_durations.py /tmp/junit.xml

``make test`` gives whole files to its two workers (pytest-xdist ``--dist loadfile``) in the order
``tests/conftest.py`` sorts them: longest first, by this file, so that no long file is handed out last and
runs alone at the end. Only the order depends on it, never a result; a file it does not list runs after
those it does. Re-run after adding a long test file, or when the suite's balance has drifted (two workers
finishing minutes apart).
"""

from __future__ import annotations

import argparse
import json
import sys
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "tests" / "durations.json"


def junit_to_file_seconds(report: Path) -> dict[str, float]:
    """{test file relative to the repository: the sum of its test cases' times (s)}, longest first."""
    seconds: Counter[str] = Counter()
    for case in ET.parse(report).getroot().iter("testcase"):
        module = case.get("classname") or ""
        if module.startswith("tests."):
            seconds[module.replace(".", "/") + ".py"] += float(case.get("time") or 0.0)
    return {name: round(value, 1) for name, value in seconds.most_common()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path, help="a JUnit XML report of the whole suite (pytest --junitxml)")
    parser.add_argument("--out", type=Path, default=OUT, help=f"where to write (default {OUT.relative_to(REPO)})")
    args = parser.parse_args(argv)
    seconds = junit_to_file_seconds(args.report)
    if not seconds:
        print(f"{args.report}: no test cases of tests/", file=sys.stderr)
        return 2
    args.out.write_text(json.dumps(seconds, indent=1) + "\n")
    print(f"{args.out}: {len(seconds)} files, {sum(seconds.values()):.0f} s of tests")
    return 0


if __name__ == "__main__":
    sys.exit(main())
