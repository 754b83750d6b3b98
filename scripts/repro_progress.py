"""`dvc repro` that says where it is: each stage DVC comes to is numbered, ``[k/N]``, N the pipeline's stages.

    python scripts/repro_progress.py [dvc repro options]      # what `make reproduce` runs

prints DVC's own output unchanged but for a prefix on the one line DVC writes per stage it comes to,
in the order it comes to them::

    [31/176] Stage 'make_training_set' didn't change, skipping
    [32/176] Running stage 'train_ae':
    [33/176] Stage 'encode_database@002_master_chef_can' is cached - skipping run, checking out outputs

It is one plain `dvc repro` underneath, started through ``dvc_fast_lock.py`` (DVC's own code but for a
faster update of dvc.lock after each stage, writing the same bytes), so everything of DVC's holds: the run cache, stopping at the
first failing stage (the exit status is DVC's), and a re-run going on from the last finished stage
(whose first lines then count the stages already done). The counter reads DVC's stdout as it comes;
the stages' progress bars (stderr) pass straight through. N comes from `dvc stage list` (one DVC
start-up, ~2 s, once): DVC comes to every stage of the pipeline exactly once when it reproduces all of
it. With a target on the command line, DVC comes to only some of them: then no N (``[k]``).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path

# The DVC of this Python's environment (.venv under make), dvc.lock updated as DVC would, faster (see that script).
DVC = [sys.executable, str(Path(__file__).with_name("dvc_fast_lock.py"))]

# The one line DVC's `repro` logs for each stage it comes to: run, unchanged, or restored from the run cache.
STAGE_LINE = re.compile(rb"^(?:Running stage '[^']+':|Stage '[^']+' (?:didn't change, skipping|is cached - skipping run))")


def count_stages(dvc: list[str] = DVC) -> int:
    """How many stages the pipeline has (``dvc stage list --name-only``, foreach and matrix items each one)."""
    names = subprocess.run([*dvc, "stage", "list", "--name-only"], capture_output=True, check=True).stdout
    return len(names.splitlines())


def annotate(lines: Iterable[bytes], total: int | None) -> Iterator[bytes]:
    """DVC's output lines (bytes, as read), each stage's line prefixed with ``[k/total] `` (``[k] `` without a total)."""
    k = 0
    for line in lines:
        if STAGE_LINE.match(line):
            k += 1
            line = (f"[{k}/{total}] " if total else f"[{k}] ").encode() + line
        yield line


def main(argv: list[str] | None = None, dvc: list[str] = DVC) -> int:
    args = sys.argv[1:] if argv is None else argv
    total = None if any(not a.startswith("-") for a in args) else count_stages(dvc)
    # Unbuffered: the stages' own prints (same pipe) then come out in order with DVC's lines, not in blocks.
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    # Bytes, not text: a stage's output passes through exactly as written (no newline translation).
    proc = subprocess.Popen([*dvc, "repro", *args], stdout=subprocess.PIPE, env=env)
    # Ctrl-C reaches DVC too (same process group): DVC stops the stage and exits, and this process must
    # keep copying its last lines and return its status rather than die first. DVC already runs (Popen
    # returns after the exec), so it keeps the default handling.
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        out = sys.stdout.buffer
        for line in annotate(iter(proc.stdout.readline, b""), total):
            out.write(line)
            out.flush()
        status = proc.wait()
    finally:
        signal.signal(signal.SIGINT, previous)
    return status if status >= 0 else 128 - status  # killed by signal s: 128 + s, as a shell reports it


if __name__ == "__main__":
    sys.exit(main())
