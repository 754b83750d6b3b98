"""``tactile6d bench identify``: seconds per identification on the paper's triplets, and peak memory.

Identifies each of the paper's triplets (L = 3) of every library object that has some (``tactile6d
.identifier``) against the library: every object of ``objects.names`` with artifacts, or the
``--object`` ones. After one warm-up identification, each triplet is timed once (the images read once,
every object screened, the winner re-estimated in full; artifact loading is not counted). Prints the
per-step medians and how often the right object came first, then, as its last line, one JSON object
with ``median_s``, ``p90_s``, the per-step medians, ``top1``, ``peak_rss_mb`` and the 1-minute load
average, since wall-clock times depend on what else runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource

import numpy as np

from tactile6d.cli import description
from tactile6d.cli.bench_estimate import paper_triplets
from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.data.third_party import DataStore
from tactile6d.estimation.identifier import Identifier
from tactile6d.estimation.optimize import use_cpu_devices_for

STEPS = ("encode", "objects", "guess", "refine", "total")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d bench identify", description=description(__doc__))
    parser.add_argument("--object", action="append", default=None, help="library object (repeatable; default: all)")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parser.parse_args(argv)

    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    objects = args.object or [str(o) for o in cfg.objects.names]
    scenes = paper_triplets(DataStore(cfg.paths), objects)
    if not scenes:
        raise InputError(f"none of {', '.join(objects)} has triplets in the paper's set")

    with Identifier.from_artifacts(objects, artifacts, cfg) as identifier:
        print(f"{len(scenes)} triplets against a library of {len(objects)} objects, screened on {identifier.describe()}")
        _, _, T, images = scenes[0]
        identifier.identify(T, images)  # warm-up: library start-up
        seconds = {step: [] for step in STEPS}
        right = 0
        for obj, _, T, images in scenes:
            result = identifier.identify(T, images)
            right += result.best.name == obj
            for step in STEPS:
                seconds[step].append(result.seconds[step])
    medians = {step: float(np.median(v)) for step, v in seconds.items()}
    print(f"median {medians['total']:.3f} s per identification over {len(scenes)} triplets "
          f"[{', '.join(f'{s} {medians[s]:.3f}' for s in STEPS[:-1])}]; right object first in {right} of {len(scenes)}")
    print(json.dumps({
        "median_s": medians["total"],
        "p90_s": float(np.percentile(seconds["total"], 90)),
        "steps_median_s": medians,
        "n_scenes": len(scenes),
        "objects": objects,
        "top1": right / len(scenes),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "load_average_1min": os.getloadavg()[0],
        "cpu_count": os.cpu_count(),
    }))
    return 0
