"""What the tracker follows, frame by frame: each hypothesis's error and evidence, and what a re-detection offers.

    python scripts/track_hypotheses.py --artifacts ART --sequence 1 [--true-sensors] [--frames 50] [override ...]

Follows one sequence of ``ART/sequences/tracking.h5`` (stage make_sequences) with ``Tracker.update``, the default
settings, and prints one line per frame: the mode, the reported pose's positional error (cm), and every
hypothesis followed as (positional error cm, evidence mm), the reported one (least evidence) first. On a
re-detection it adds the single-shot estimate's ranked poses as (positional error cm, score mm) and which of them
it offers as distinct (``Estimate.distinct``: the poses the tracker then follows beside, or instead of, those it
had). A diagnostic for a sequence the tracker loses: whether the right pose was offered, and why it was dropped.
It writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.optimize import use_cpu_devices_for  # noqa: E402
from tactile6d.estimation.tracker import Tracker, TrackSettings  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def position_cm(pose: np.ndarray, truth: np.ndarray) -> float:
    return float(100 * np.linalg.norm(np.asarray(pose)[:3, 3] - np.asarray(truth)[:3, 3]))


def frame_line(frame: int, mode: str, error_cm: float, hypotheses: list[tuple[float, float]],
               offered: list[tuple[float, float]] | None = None, distinct: list[int] | None = None) -> str:
    """One frame: ``frame mode error`` then the hypotheses (error cm, evidence m) and, on a re-detection, the
    estimate's ranked poses (error cm, score m) and the indices it offered as distinct."""
    line = f"{frame:3d} {mode:8s} {error_cm:6.2f} cm  followed " + " ".join(
        f"({e:.2f} cm, {1000 * v:.3f})" for e, v in hypotheses)
    if offered is not None:
        line += "  re-detection ranked " + " ".join(f"({e:.2f} cm, {1000 * v:.3f})" for e, v in offered)
        line += f", offered {distinct}"
    return line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--sequence", type=int, required=True, help="index of the sequence in tracking.h5")
    parser.add_argument("--true-sensors", action="store_true", help="through the true sensor poses")
    parser.add_argument("--frames", type=int, default=None, help="follow only the first N frames")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parser.parse_args(argv)
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))  # as stage evaluate_tracking
    seq = read_artifact(layout.sequences_file(args.artifacts, "tracking"), "sequences")
    q = args.sequence
    estimator = Estimator.from_artifacts(str(seq["objects"][q]), args.artifacts, cfg)
    T = np.asarray(seq["T_world_sensors_true" if args.true_sensors else "T_world_sensors"][q])
    images, truth = np.asarray(seq["images"][q]), np.asarray(seq["T_world_object"][q])
    n = len(T) if args.frames is None else min(args.frames, len(T))
    print(f"{seq['names'][q]} ({seq['objects'][q]}), {n} frames, sensor poses "
          + ("true" if args.true_sensors else "as reported"))
    with Tracker(estimator, TrackSettings.from_cfg(cfg.track)) as tracker:
        for f in range(n):
            answer = tracker.update(T[f], images[f])
            followed = sorted(((position_cm(h.poses[-1], truth[f]), h.evidence) for h in tracker._hypotheses),
                              key=lambda row: row[1])
            offered = distinct = None
            if answer.estimate is not None:
                offered = [(position_cm(p, truth[f]), float(s)) for p, s in zip(answer.estimate.poses,
                                                                                answer.estimate.scores)]
                distinct = None if answer.estimate.distinct is None else [int(i) for i in answer.estimate.distinct]
            print(frame_line(f, answer.mode, position_cm(answer.pose, truth[f]), followed, offered, distinct), flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
