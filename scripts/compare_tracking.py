"""Did a tracker setting change the tracked error beyond chance? Per-sequence paired differences between two runs.

    python -m stages.evaluate_tracking --params params.yaml paths.artifacts_dir=ART track.evaluation.single_shot_every=90
    cp ART/metrics/tracking.json base_27.json            # then the same with the setting compared -> other_27.json
    python scripts/compare_tracking.py --base base_*.json --other other_*.json

Each ``--base`` file (an ``evaluate_tracking`` metrics file, ``artifacts/metrics/tracking.json``) is paired with the
``--other`` file in the same place: the same sequences (their names must match), tracked under two settings. Prints,
per pair, both runs' tracked positional error over all frames, median (mean) cm, and which sequences were over
``lost_threshold`` (2 cm) for longer than ``--over`` seconds (issue 37's 0.5 s); then, pooled over every pair, how
many sequences were over that long and for how many seconds in all, and the mean per-sequence difference (other
minus base) of the sequences' mean and median errors, each with its bootstrap 90 % interval (``--resamples`` draws
of the sequences, seed 0; ``compare_errors.paired_difference``). A difference whose interval holds 0 is within what
the sequences' draw alone moves. Reads the files only.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # scripts/, for compare_errors

from compare_errors import paired_difference  # noqa: E402


@dataclass(frozen=True)
class TrackingRun:
    """One ``evaluate_tracking`` metrics file: names (Q,), the longest run over the lost threshold (Q,) s, and each
    sequence's tracked positional error per frame (Q lists of F_q values, cm)."""

    names: list[str]
    longest_over_s: np.ndarray
    errors_cm: list[np.ndarray]

    @classmethod
    def read(cls, path: str) -> TrackingRun:
        metrics = json.loads(Path(path).read_text())
        sequences, frames = metrics["sequences"], metrics["frames"]
        if len(sequences) != len(frames):
            raise SystemExit(f"{path}: {len(sequences)} sequences but {len(frames)} frame records")
        return cls([q["name"] for q in sequences], np.array([q["longest_over_s"] for q in sequences], dtype=float),
                   [100.0 * np.asarray(f["track_position_m"], dtype=np.float64) for f in frames])

    def per_sequence(self, statistic) -> np.ndarray:
        """(Q,) cm: ``statistic`` (np.mean, np.median) of each sequence's errors over its frames."""
        return np.array([statistic(e) for e in self.errors_cm])

    def lost(self, over: float) -> list[tuple[str, float]]:
        """(name, seconds) of the sequences over the lost threshold for longer than ``over`` seconds."""
        return [(n, float(s)) for n, s in zip(self.names, self.longest_over_s) if s > over]

    def summary(self) -> str:
        every = np.concatenate(self.errors_cm)
        return f"{np.median(every):.2f} ({every.mean():.2f})"


def lost_text(run: TrackingRun, over: float) -> str:
    return ", ".join(f"{name} {seconds:.2f} s" for name, seconds in run.lost(over)) or "none"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", nargs="+", required=True, help="evaluate_tracking metrics files, the reference run")
    parser.add_argument("--other", nargs="+", required=True, help="the same sequences under the setting compared")
    parser.add_argument("--over", type=float, default=0.5, help="s: a sequence lost for longer counts (issue 37)")
    parser.add_argument("--resamples", type=int, default=4000)
    args = parser.parse_args(argv)
    if len(args.base) != len(args.other):
        raise SystemExit(f"{len(args.base)} --base and {len(args.other)} --other files: one of each per pair")
    pooled: dict[str, list] = {"base": [], "other": []}
    for base_path, other_path in zip(args.base, args.other):
        base, other = TrackingRun.read(base_path), TrackingRun.read(other_path)
        if base.names != other.names:
            raise SystemExit(f"{base_path} and {other_path} hold other sequences: {base.names} against {other.names}")
        print(f"{other_path} against {base_path}: {other.summary()} cm against {base.summary()}; "
              f"over {args.over} s: {lost_text(other, args.over)} against {lost_text(base, args.over)}")
        pooled["base"].append(base)
        pooled["other"].append(other)
    counts = {}
    for side, runs in pooled.items():
        lost = [seconds for run in runs for _, seconds in run.lost(args.over)]
        counts[side] = f"{len(lost)} of {sum(len(run.names) for run in runs)} over {args.over} s, {sum(lost):.1f} s in all"
    print(f"all: {counts['other']} against {counts['base']}")
    for label, statistic in (("mean", np.mean), ("median", np.median)):
        base = np.concatenate([run.per_sequence(statistic) for run in pooled["base"]])
        other = np.concatenate([run.per_sequence(statistic) for run in pooled["other"]])
        mean, low, high = paired_difference(base, other, args.resamples, np.random.default_rng(0))
        print(f"all: per sequence, {label} over frames {mean:+.3f} cm [{low:+.3f}, {high:+.3f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
