"""The command line of the developer scripts (``scripts/``): options, then Hydra-style ``key=value`` overrides
anywhere on the line.

argparse gives a list option (``--scenes kinematic validation``) every word up to the next option, so an
override written after it (``--scenes kinematic sensors.pose_sigma_mm=3``) would be taken for a scene set
and the run would silently use the defaults. ``parse_with_overrides`` takes the overrides out first.
"""

from __future__ import annotations

import argparse
import sys


def is_override(word: str) -> bool:
    """A ``key=value`` config override (``rank.candidates=60``, ``+x=1``, ``~y=null``), not an option
    (``--out=FILE``) and not a bare value."""
    return "=" in word and not word.startswith("-") and not word.startswith("=")


def parse_with_overrides(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> argparse.Namespace:
    """``parser.parse_args`` of argv (default ``sys.argv[1:]``) less its overrides, which go, in their order, to
    ``args.overrides`` wherever they stood on the line. A value of an option must then not contain ``=``."""
    words = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args([w for w in words if not is_override(w)])
    args.overrides = [w for w in words if is_override(w)]
    return args
