"""Start a command again with every numerical library capped at AVX2, where it could not cap itself.

``tactile6d.runtime.instruction_sets.pin()`` works only before NumPy and the other libraries are imported, which
the stages manage (``stages/__init__.py``). The diagnostic scripts of scripts/ import NumPy at the top, yet their
figures are quoted in docs/ and must repeat on every CPU as the stages' outputs do: each calls ``run_pinned()``
first under ``if __name__ == "__main__":``. Kept apart from ``instruction_sets`` (which every stage lists among its
DVC dependencies) since no stage uses it. Imports nothing heavy.
"""

from __future__ import annotations

import os
import sys

from tactile6d.runtime.instruction_sets import PINNED_VARIABLES, pinned_environment


def run_pinned() -> None:
    """Make sure this process runs pinned: when its environment lacks a cap, start it again with the caps.

    It replaces the process (``os.execve``, the same interpreter and command line, ``sys.orig_argv``) with one
    whose environment is ``pinned_environment(os.environ)``; in that process, or where the environment is already
    pinned (a stage, a shell that exported ``python -m tactile6d.runtime.instruction_sets``), it returns at once.
    Call it under ``if __name__ == "__main__":``, not in ``main()``: a test calling ``main()`` would be replaced.
    """
    pinned = pinned_environment(os.environ)
    if all(os.environ.get(name) == pinned[name] for name in PINNED_VARIABLES):
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, list(sys.orig_argv), pinned)
