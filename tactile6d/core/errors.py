"""The project's exceptions. Each carries a message meant to be printed as one line to a user."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator


class Tactile6dError(Exception):
    """Base class: an error a user can act on, with a one-line message."""


class ConfigError(Tactile6dError):
    """A missing or invalid configuration key or value."""


class DataError(Tactile6dError):
    """Third-party input data missing, unreadable, corrupt or not as expected."""


class MeshError(Tactile6dError):
    """A mesh that cannot be used (degenerate, wrong units, unreadable)."""


class ArtifactError(Tactile6dError):
    """A stage artifact that is missing, corrupt or of the wrong schema."""


class InputError(Tactile6dError):
    """Bad input to the estimator or the CLI (poses, images, scene folders)."""


class NoMatch(Tactile6dError):
    """Valid input that nothing in the object's database matches: no database image close enough to a
    sensor's image, or no tuple of database points at the sensors' pairwise distances.

    An outcome, not a mistake of the caller: an evaluation counts it as a failed estimate, whereas an
    ``InputError`` there means the data itself is wrong and must stop the run. A wrong object name or a
    sensor pose far from the object typically ends here.
    """


class Interrupted(KeyboardInterrupt):
    """A stage stopped by a signal (SIGTERM): raised where the stage is, so that it unwinds as on Ctrl-C
    (temporary files removed, worker processes ended). ``signum``: the signal's number."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum

    def __str__(self) -> str:
        return signal.Signals(self.signum).name


# What ``exit_on_error`` runs when an interrupt ends a stage, registered by the modules that start
# something the interpreter would otherwise wait for (tactile6d.runtime.executor: its pools' workers). A list
# here rather than an import there: tactile6d.core.errors is the bottom layer and imports no other module.
_ON_INTERRUPT: list[Callable[[], None]] = []


def on_interrupt(cleanup: Callable[[], None]) -> None:
    """Have ``exit_on_error`` call ``cleanup()`` when an interrupt (Ctrl-C, SIGTERM) ends the program."""
    if cleanup not in _ON_INTERRUPT:
        _ON_INTERRUPT.append(cleanup)


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


@contextlib.contextmanager
def _sigterm_raises() -> Iterator[None]:
    """SIGTERM raises ``Interrupted`` meanwhile (Python's default would end the process on the spot,
    skipping every ``finally``, and leave the worker processes running). Only in the main thread, the
    only one that may set a signal handler."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_interrupted)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _program_name() -> str:
    """What was interrupted, for its one line: the DVC stage (``$DVC_STAGE``), else the module run with
    ``python -m``, else the script."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    return os.environ.get("DVC_STAGE") or (spec.name if spec is not None else os.path.basename(sys.argv[0]))


def exit_on_error(main: Callable[[], int | None]) -> int:
    """Run ``main``; turn a Tactile6dError into ``error: <message>`` on stderr and exit status 2, and an
    interrupt (Ctrl-C, SIGTERM) into one line on stderr and status 128 + the signal (130, 143).

    Under ``exit_on_error`` SIGTERM unwinds like Ctrl-C (``Interrupted``); what is unwound on the way
    (``finally``, ``with``) removes temporary files and ends worker processes, and any worker left is
    ended here, so that the process exits within about a second (docs/distributed.md, "Ctrl-C").
    """
    try:
        with _sigterm_raises():
            return int(main() or 0)
    except Tactile6dError as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        # e.g. the worker processes of a pool nobody closed, which the interpreter would wait for at exit
        # (those of a closed executor or renderer are gone already: executor.shutdown_pool).
        for cleanup in _ON_INTERRUPT:
            cleanup()
        print(f"interrupted: {_program_name()} stopped by {signal.Signals(signum).name} before it finished; "
              "run it again", file=sys.stderr)
        return 128 + signum
