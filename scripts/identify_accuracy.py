"""Identification accuracy and time on a scene set against the library (tune on validation/offaxis only).

    python scripts/identify_accuracy.py --artifacts artifacts --scenes offaxis [key=value ...]

Each scene is identified (``Identifier.identify``) against every object of ``objects.names``, with the
weights of the calibrate_identify stage (or ``identify.weights=[...]``). Prints one line per scene
(true object, the winner, its probability, seconds) and a last line of JSON: top-1 and top-3 accuracy,
the median and p90 seconds per identification, and the position error of the winner's pose (cm, median)
on the scenes identified correctly. Reads the artifacts only.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d import layout
from tactile6d.config import compose_config
from tactile6d.identifier import Identifier
from tactile6d.io import read_artifact
from tactile6d.optimize import use_cpu_devices_for


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", default="offaxis")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    objects = [str(o) for o in cfg.objects.names]
    identifier = Identifier.from_artifacts(objects, args.artifacts, cfg)
    scenes = read_artifact(layout.scenes_file(args.artifacts, args.scenes), "scenes")
    ranks, seconds, errors = [], [], []
    for s in range(len(scenes["names"])):
        truth = str(scenes["objects"][s])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = identifier.identify(scenes["T_world_sensors"][s], scenes["images"][s])
        names = [o.name for o in result.objects]
        ranks.append(names.index(truth))
        seconds.append(result.seconds["total"])
        if ranks[-1] == 0:
            errors.append(100 * np.linalg.norm(result.best.pose[:3, 3] - scenes["T_world_object"][s][:3, 3]))
        print(f"{scenes['names'][s]}: {result.best.name} p {result.best.probability:.3f} "
              f"({'right' if ranks[-1] == 0 else f'truth ranked {ranks[-1] + 1}'}), {seconds[-1]:.2f} s", flush=True)
    ranks = np.array(ranks)
    print(json.dumps({
        "scenes": args.scenes, "n": int(len(ranks)), "objects": len(objects), "overrides": args.overrides,
        "top1": round(float(np.mean(ranks == 0)), 4), "top3": round(float(np.mean(ranks < 3)), 4),
        "median_s": round(float(np.median(seconds)), 3), "p90_s": round(float(np.percentile(seconds, 90)), 3),
        "pos_err_cm_median_correct": round(float(np.median(errors)), 3) if errors else None,
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
