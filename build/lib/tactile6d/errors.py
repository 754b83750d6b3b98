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


class NoMatch(Tactile6dError):
    """Valid input that nothing in the object's database matches: no database image close enough to a
    sensor's image, or no tuple of database points at the sensors' pairwise distances.

    An outcome, not a mistake of the caller: an evaluation counts it as a failed estimate, whereas an
    ``InputError`` there means the data itself is wrong and must stop the run. A wrong object name or a
    sensor pose far from the object typically ends here.
    """


def exit_on_error(main: Callable[[], int | None]) -> int:
    """Run ``main``; turn a Tactile6dError into ``error: <message>`` on stderr and exit status 2."""
    try:
        return int(main() or 0)
    except Tactile6dError as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
