"""``tactile6d bench track``: frames per second of the tracker at L = 3 on the generated sequences.

Feeds the sequences of ``artifacts/sequences/tracking.h5`` (stage make_sequences; three sensors, 30 frames per
second, sensor poses as a hand reports them) as streams to each object's ``Tracker.track`` with the config's
``track`` section (overrides accepted): this process follows the frames while ``track.read_ahead`` reader
processes, one set for all the sequences, read the next frame's contact patches (``track.read_ahead=0``: each
frame read in its turn, on ``track.threads`` threads). The first frame of each sequence is a re-detection (a
single-shot estimate); one warm-up sequence is run first (library start-up, JAX compilation, the readers' start).

Prints, per sequence, the median seconds of an update frame and the re-detections; then, as its last line,
one JSON object: ``update_median_ms``, ``update_p90_ms``, ``fps_updates`` (1 / the median update),
``fps_all`` (frames over the total time, re-detections included), ``redetections``, ``frames``, the
``threads`` and ``read_ahead`` processes used, the machine's cores and 1-minute load average, since
wall-clock times depend on what else runs.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from tactile6d.cli import description
from tactile6d.core.config import compose_config
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.estimation.tracker import Tracker, TrackSettings
from tactile6d.perception.patch_reader import PatchReader


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d bench track", description=description(__doc__))
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--sequences", type=int, default=None, help="time the first N sequences (default: all)")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (e.g. track.threads=1)")
    args = parser.parse_args(argv)

    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    art = read_artifact(layout.sequences_file(artifacts, "tracking"), "sequences")
    settings = TrackSettings.from_cfg(cfg.track)
    n = len(art["objects"]) if args.sequences is None else min(args.sequences, len(art["objects"]))
    estimators: dict[str, Estimator] = {}

    # One set of reader processes for every sequence's tracker, as a program that tracks object after object keeps.
    reader = PatchReader(settings.read_ahead) if settings.read_ahead > 0 else None

    def run(q: int) -> tuple[np.ndarray, list[str], float]:
        obj = str(art["objects"][q])
        if obj not in estimators:
            estimators[obj] = Estimator.from_artifacts(obj, artifacts, cfg)
        T, images = np.asarray(art["T_world_sensors"][q]), np.asarray(art["images"][q])
        with Tracker(estimators[obj], settings, reader) as tracker:
            start = time.perf_counter()
            answers = list(tracker.track(zip(T, images)))
            total = time.perf_counter() - start
        return np.array([a.seconds for a in answers]), [a.mode for a in answers], total

    try:
        run(0)  # warm-up (and the reader processes' start)
        seconds, modes, total = measure(run, n, art["names"])
    finally:
        if reader is not None:
            reader.close()
    updates = np.array([x == "update" for x in modes])
    median = float(np.median(seconds[updates]))
    print(json.dumps({
        "update_median_ms": round(1e3 * median, 2),
        "update_p90_ms": round(1e3 * float(np.percentile(seconds[updates], 90)), 2),
        "fps_updates": round(1.0 / median, 2),
        "fps_all": round(len(seconds) / total, 2),
        "redetections": int(sum(x == "redetect" for x in modes)),
        "frames": len(seconds),
        "threads": settings.threads,
        "read_ahead": settings.read_ahead,
        "cores": os.cpu_count(),
        "load_1min": round(os.getloadavg()[0], 2),
    }))
    return 0


def measure(run, n: int, names) -> tuple[np.ndarray, list[str], float]:
    """The first n sequences tracked by ``run`` (q -> frame seconds, modes, total seconds), each one's line
    printed -> every frame's seconds, modes, and the total seconds."""
    seconds, modes, total = [], [], 0.0
    for q in range(n):
        s, m, t = run(q)
        updates = np.array([x == "update" for x in m])
        print(f"{names[q]}: {len(m)} frames, update median {1e3 * np.median(s[updates]):.1f} ms, "
              f"{sum(x == 'redetect' for x in m)} re-detections", flush=True)
        seconds.append(s)
        modes += m
        total += t
    return np.concatenate(seconds), modes, total
