"""Record the wall time of `make reproduce` as a whole: ``artifacts/times/make_reproduce.json``.

    python scripts/record_reproduce_time.py STARTED   # STARTED: the target's start, seconds since the epoch

The Makefile takes STARTED (``date +%s``) when it reads the `reproduce` target, so before the venv install, and
runs this after `dvc repro`; scripts/update_readme.py then writes the figure into the README. Beside the
target's own time (a ``tactile6d.runtime.stage_clock`` record named ``make reproduce``), the file says what the run
held: how many of the pipeline's stages DVC ran in it (their time records started after STARTED; the
others were unchanged or restored from the run cache and keep older records) and their summed seconds,
whether the venv was installed in it, and whether the data came from a local copy (``DATA=``).
"""

from __future__ import annotations

import datetime
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tactile6d from this checkout, as the stages

from tactile6d.runtime import stage_clock  # noqa: E402

OUT = stage_clock.TIMES_DIR / "make_reproduce.json"
INSTALLED = Path(".venv") / ".installed"  # the Makefile's install stamp


def pipeline_records() -> list[dict]:
    """Every stage's time record: those under artifacts/times/stages and the report stage's beside them."""
    report = [r for r in stage_clock.read_records(stage_clock.TIMES_DIR) if r["stage"] == "report"]
    return stage_clock.read_records() + report


def reproduce_record(started: float, now: float, records: list[dict], installed: bool, local_data: bool) -> dict:
    """The record of a `make reproduce` that ran from ``started`` to ``now`` (epoch seconds), given the stages'
    time records as they are at its end."""
    since = datetime.datetime.fromtimestamp(started).astimezone()
    ran = [r for r in records if datetime.datetime.fromisoformat(r["started"]) >= since]
    rec = stage_clock.record("make reproduce", now - started, datetime.datetime.fromtimestamp(now))
    rec.update(stages=len(records), stages_run=len(ran), stages_run_seconds=round(sum(r["seconds"] for r in ran), 2),
               installed=installed, local_data=local_data)
    return rec


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    started, now = float(args[0]), time.time()
    installed = INSTALLED.is_file() and INSTALLED.stat().st_mtime >= started
    rec = reproduce_record(started, now, pipeline_records(), installed, bool(os.environ.get("TACTILE6D_DATA")))
    stage_clock.write_record(OUT, rec)
    print(f"{OUT}: make reproduce took {rec['seconds']:.0f} s; DVC ran {rec['stages_run']} of {rec['stages']} stages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
