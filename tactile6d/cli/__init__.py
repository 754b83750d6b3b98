"""The ``tactile6d`` console script: dispatches to ``tactile6d.cli.<module>.main(argv)``, one module per command;
``objects`` holds what the commands share: the objects they know by name and where their artifacts live.

Sub-command modules are imported only when used, so ``tactile6d --help`` stays fast and a command's
heavy dependencies (torch, jax) load only for that command.

Layer 8 of 8, the top: it imports from every layer below.
"""

from __future__ import annotations

import functools
import importlib
import re
import sys
import warnings

from tactile6d.core.errors import exit_on_error

# command words -> (module under tactile6d.cli, one-line help)
COMMANDS: dict[tuple[str, ...], tuple[str, str]] = {
    ("fidelity",): ("fidelity", "compare the simulator with the paper's 120 TACTO images (IoU, correlation, montage)"),
    ("bench", "render"): ("bench_render", "images per second of the DIGIT simulator"),
    ("bench", "estimate"): ("bench_estimate", "seconds per estimate (default, baseline, faithful) and peak memory"),
    ("bench", "identify"): ("bench_identify", "seconds per identification of the paper's triplets against the object library"),
    ("bench", "batch"): ("bench_batch", "start-up and per-scene seconds of one `estimate` call on the paper's triplets"),
    ("bench", "add-object"): ("bench_add_object", "seconds of `tactile6d add-object` on a mesh of about 20 000 faces"),
    ("bench", "track"): ("bench_track", "frames per second of the tracker on the generated sequences (L = 3)"),
    ("estimate",): ("estimate", "estimate an object's pose from scene folders in the paper's triplet layout"),
    ("track",): ("track", "follow an object's pose over a stream of frames (numbered scene folders or a ROS 2 bag)"),
    ("inspect",): ("inspect", "what the estimator reads from one scene's images (light, contact patch, problems), with a figure"),
    ("identify",): ("identify", "which object of a library touches the sensors, and its pose (one scene folder)"),
    ("calibrate-sensors",): ("calibrate_sensors", "each sensor's mounting offset, from grasps of a known object at a known pose"),
    ("add-object",): ("add_object", "a mesh file of yours as a library object: check it, configure it, make its artifacts"),
}


def description(doc: str) -> str:
    """A command module's docstring -> its first line as ``--help`` shows it: reST's ``code`` marks taken out."""
    return re.sub(r"``([^`]*)``", r"\1", doc.strip().splitlines()[0])


def usage() -> str:
    lines = ["usage: tactile6d COMMAND [ARGS...]", "", "commands:"]
    for words, (_, text) in COMMANDS.items():
        lines.append(f"  {' '.join(words):<18}{text}")
    lines.append("")
    lines.append("Run `tactile6d COMMAND --help` for a command's options.")
    return "\n".join(lines)


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning no command turned into its own lines -> one ``warning: <message>`` line on stderr, as the
    commands write theirs, not Python's ``file:line: Category: message`` with the source line."""
    print(f"warning: {' '.join(str(message).split())}", file=sys.stderr if file is None else file)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    warnings.showwarning = show_warning
    for words, (module_name, _) in sorted(COMMANDS.items(), key=lambda kv: -len(kv[0])):
        if tuple(argv[: len(words)]) == words:
            try:
                module = importlib.import_module(f"tactile6d.cli.{module_name}")
            except ModuleNotFoundError as exc:
                if exc.name == f"tactile6d.cli.{module_name}":
                    print(f"error: command {' '.join(words)!r} is not available in this version", file=sys.stderr)
                    return 2
                raise
            rest = argv[len(words) :]
            return exit_on_error(functools.partial(module.main, rest))
    print(usage(), file=sys.stdout if argv[:1] in (["-h"], ["--help"]) else sys.stderr)
    return 0 if argv[:1] in (["-h"], ["--help"]) else 2


if __name__ == "__main__":
    sys.exit(main())
