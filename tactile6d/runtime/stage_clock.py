"""Each DVC stage's wall time, recorded by the stage itself: one small JSON file per stage run.

A stage wraps its ``main`` once, where it runs as a program::

    sys.exit(exit_on_error(timed(main)))

Run by DVC (which names the stage in ``$DVC_STAGE``, e.g. ``render_database@004_sugar_box`` or
``select_tuples@caddeo2023-ours``) and returning 0, the stage then writes
``artifacts/times/stages/<stage>.json`` (the path dvc.yaml declares as its ``metrics`` output)::

    {"stage": "sample_surface@prim_box", "seconds": 0.82,
     "started": "2026-11-24T21:24:52+00:00", "finished": "2026-11-24T21:24:53+00:00",
     "cpu": "AMD EPYC", "cores": 2}

``seconds`` runs from the start of the process, so Python's start-up and the stage's imports (torch
alone, 1.6-1.8 s on the 2-core machine) count: it is the time DVC waits for the command, less DVC's own bookkeeping. A
stage that raises (a ``Tactile6dError``, Ctrl-C) or returns non-zero writes nothing, and the file is
written atomically, so a time file always means a finished stage. Run by hand (no ``$DVC_STAGE``),
a stage writes none. The report stage reads ``artifacts/times/stages`` and so writes its own time
beside that folder (``timed(main, TIMES_DIR)``), not in it.

Nothing here imports the rest of tactile6d or a third-party package: every stage lists this module
as a dep (tests/test_dvc.py), and it should add nothing else to any stage's deps.
"""

from __future__ import annotations

import datetime
import functools
import json
import os
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

TIMES_DIR = Path("artifacts") / "times"  # relative to the repository root, where DVC runs the stages
STAGES_DIR = TIMES_DIR / "stages"

# When this module was imported: the fallback start of the process where /proc cannot tell it.
_IMPORTED = time.perf_counter()


def process_seconds() -> float:
    """Seconds since this process started: from Linux's /proc (both clocks count from boot, to 10 ms),
    else since this module was imported (then the interpreter's start-up and earlier imports are missed)."""
    try:
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        # The command name (field 2) may hold spaces and brackets: count the fields after its last ')'.
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")  # field 22, starttime, in clock ticks
        return max(uptime - started, 0.0)
    except (OSError, ValueError, IndexError):
        return time.perf_counter() - _IMPORTED


def cpu_model() -> str:
    """The CPU's model name (e.g. ``AMD EPYC``): Linux's /proc/cpuinfo, else what ``platform`` says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return " ".join(line.split(":", 1)[1].split())
    except OSError:
        pass
    return platform.processor() or platform.machine()


def record(name: str, seconds: float, finished: datetime.datetime | None = None) -> dict:
    """The time record of a run of ``name`` that took ``seconds`` and ended at ``finished`` (default:
    now): name, seconds (rounded to 10 ms), ISO start and end with the local UTC offset, CPU, cores."""
    finished = (finished or datetime.datetime.now()).astimezone().replace(microsecond=0)
    started = finished - datetime.timedelta(seconds=round(seconds))
    return {"stage": name, "seconds": round(float(seconds), 2), "started": started.isoformat(),
            "finished": finished.isoformat(), "cpu": cpu_model(), "cores": os.cpu_count()}


def write_record(path: str | os.PathLike, rec: dict) -> Path:
    """Write a time record as JSON atomically (temporary file beside it, then rename); returns the path.

    ``hdf5.write_text`` does the same, but importing tactile6d.data.hdf5 (NumPy, h5py) would add its code to every
    stage's deps: this module stays standalone."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=path.name + ".tmp-", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(rec, indent=2, sort_keys=True) + "\n")
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return path


def timed(main: Callable[..., int | None], directory: str | os.PathLike = STAGES_DIR) -> Callable[..., int]:
    """``main`` that, when it returns 0 (or None) in a stage run by DVC, writes ``<directory>/<$DVC_STAGE>.json``.

    Exceptions pass through untouched and write nothing (``exit_on_error`` outside turns them into exit
    status 2); so does a non-zero return. Returns ``main``'s status as an int.
    """

    @functools.wraps(main)
    def run(*args, **kwargs) -> int:
        status = int(main(*args, **kwargs) or 0)
        stage = os.environ.get("DVC_STAGE")
        if status == 0 and stage:
            write_record(Path(directory) / f"{stage}.json", record(stage, process_seconds()))
        return status

    return run


def duration(seconds: float) -> str:
    """Seconds as the README writes durations: ``42 s``, ``8 min 5 s``, ``70 min 11 s`` (no hours)."""
    s = round(seconds)
    return f"{s} s" if s < 60 else f"{s // 60} min {s % 60} s"


def read_records(directory: str | os.PathLike = STAGES_DIR) -> list[dict]:
    """Every time record in ``directory`` (``*.json``), ordered by start (ties by name); [] when it is missing."""
    paths = sorted(Path(directory).glob("*.json")) if Path(directory).is_dir() else []
    records = [json.loads(p.read_text()) for p in paths]
    # by the instant, not the string: records made either side of a change of UTC offset still sort right
    return sorted(records, key=lambda r: (datetime.datetime.fromisoformat(r["started"]), r["stage"]))
