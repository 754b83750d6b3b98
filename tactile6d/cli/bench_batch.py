"""``tactile6d bench batch``: start-up and per-scene seconds of one ``tactile6d estimate`` call on many scenes.

Runs ``tactile6d estimate --object auto --scenes-root ROOT --json`` once, as a separate process (so
that its imports count), on the paper's triplets by default, and timestamps each JSON line as it
arrives. It reports:

- ``startup_s``: from starting the process to its first result, less that scene's own estimate time:
  interpreter and library imports, the config, reading the scene and loading the first object's
  artifacts (``first_load_s`` of it);
- ``first_estimate_s``: the first scene's estimate, which includes one-off compilation;
- ``per_scene_s``: the mean wall-clock time between results after the first (what each further scene
  costs, the artifact loads of the later objects included), and its median ``per_scene_median_s``;
- ``estimate_median_s`` and ``later_load_median_s``: the estimates and the artifact loads after the
  first, as the command reports them.

Wall-clock timings depend on what else runs on the machine: the JSON on the last line reports the
1-minute load average next to them, and the CPU time of the whole call (``cpu_s``), which depends on
it less.

    tactile6d bench batch [--scenes-root DIR] [--object NAME|auto] [--artifacts DIR] [key=value ...]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import tactile6d
from tactile6d.cli import description
from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.data.third_party import DataStore, group_names


def paper_triplets_root(cfg) -> Path:
    """The folder that holds the paper's triplets (``<object>/triplet_<k>``), verified in the data directory."""
    groups = [g for g in group_names() if g.startswith("triplets:")]
    files = DataStore(cfg.paths).fetch_all(groups)
    return files[0].parents[2]


def estimate_command(args: argparse.Namespace, root: Path, artifacts: str) -> list[str]:
    """The ``tactile6d estimate`` call that is timed."""
    return [sys.executable, "-m", "tactile6d.cli", "estimate", "--object", args.object, "--scenes-root", str(root),
            "--artifacts", str(artifacts), "--json", "--no-progress", *args.overrides]


def run_timed(command: list[str]) -> tuple[list[float], list[dict], int, list[str], float]:
    """Run the command; seconds from its start to each stdout line, the lines as JSON, its exit status,
    its stderr lines and the CPU seconds (user + system) it used."""
    env = dict(os.environ)
    # The child must run this very code, wherever the bench is started from.
    package_parent = str(Path(tactile6d.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_parent, env.get("PYTHONPATH")) if p)
    arrivals, results = [], []
    cpu_before = _children_cpu_seconds()
    with tempfile.TemporaryFile(mode="w+") as stderr:  # a file, not a pipe: nothing can block on it
        start = time.perf_counter()
        with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=stderr, text=True, env=env) as proc:
            for line in proc.stdout:
                arrivals.append(time.perf_counter() - start)
                results.append(json.loads(line))
        stderr.seek(0)
        errors = stderr.read().splitlines()
    return arrivals, results, proc.returncode, errors, _children_cpu_seconds() - cpu_before


def _children_cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timings(arrivals: list[float], results: list[dict]) -> dict:
    """Start-up and per-scene figures from the arrival times and the results (see the module docstring)."""
    first_estimate = results[0]["seconds"]["total"]
    gaps = np.diff(arrivals)
    later = results[1:]
    later_loads = [r["load_seconds"] for r in later if r["load_seconds"] > 0]
    return {
        "startup_s": arrivals[0] - first_estimate,
        "first_load_s": results[0]["load_seconds"],
        "first_estimate_s": first_estimate,
        "per_scene_s": float(gaps.mean()) if gaps.size else None,
        "per_scene_median_s": float(np.median(gaps)) if gaps.size else None,
        "estimate_median_s": float(np.median([r["seconds"]["total"] for r in later])) if later else None,
        "later_loads": len(later_loads),
        "later_load_median_s": float(np.median(later_loads)) if later_loads else None,
        "total_s": arrivals[-1],
    }


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d bench batch", description=description(__doc__))
    parser.add_argument("--scenes-root", default=None, metavar="DIR",
                        help="folder of scene folders (default: the paper's triplets in the data directory)")
    parser.add_argument("--object", default="auto", help="object of every scene, or 'auto' (default)")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value, passed to tactile6d estimate")
    args = parser.parse_args(argv)

    cfg = compose_config(args.overrides)  # a bad override fails here, not in the child
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    root = Path(args.scenes_root) if args.scenes_root is not None else paper_triplets_root(cfg)
    command = estimate_command(args, root, artifacts)
    print("timing: " + " ".join(command[1:]))
    arrivals, results, status, errors, cpu_seconds = run_timed(command)
    if not results:
        raise InputError(f"tactile6d estimate gave no result (exit status {status}): "
                         f"{errors[-1] if errors else 'no message'}")
    failed = [line for line in errors if line.startswith("error: ") and " scenes failed" not in line]
    out = timings(arrivals, results)
    print(f"{len(results)} scenes estimated, {len(failed)} failed, in {out['total_s']:.1f} s "
          f"({cpu_seconds:.1f} s of CPU time)")
    print(f"start-up (imports, config, first artifacts load of {out['first_load_s']:.2f} s): "
          f"{out['startup_s']:.2f} s; first estimate {out['first_estimate_s']:.2f} s")
    if out["per_scene_s"] is not None:
        print(f"per scene after the first: {out['per_scene_s']:.3f} s mean, {out['per_scene_median_s']:.3f} s "
              f"median (estimate {out['estimate_median_s']:.3f} s median; {out['later_loads']} later artifact "
              f"loads" + (f", {out['later_load_median_s']:.2f} s median)" if out["later_loads"] else ")"))
    out.update(
        n_scenes=len(results),
        n_failed=len(failed),
        exit_status=status,
        cpu_s=cpu_seconds,
        method=results[0]["method"],
        solver=results[0]["solver"],
        load_average_1min=os.getloadavg()[0],
        cpu_count=os.cpu_count(),
    )
    print(json.dumps(out))
    return 0
