"""The project's exceptions. Each carries a message meant to be printed as one line to a user."""

from __future__ import annotations

import sys
from collections.abc import Callable


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


def exit_on_error(main: Callable[[], int | None]) -> int:
    """Run ``main``; turn a Tactile6dError into ``error: <message>`` on stderr and exit status 2."""
    try:
        return int(main() or 0)
    except Tactile6dError as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
