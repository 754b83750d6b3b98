"""Did a setting change the best pose's error beyond chance? Per-scene paired differences between two runs.

    python scripts/eval_accuracy.py --artifacts ART --scenes kinematic --out base_kinematic_4.npz
    python scripts/eval_accuracy.py --artifacts ART --scenes kinematic --out free_kinematic_4.npz rank.refine_free_weight=3
    python scripts/compare_errors.py --base base_*.npz --other free_*.npz --groups kinematic ...

Each ``--base`` file is paired with the ``--other`` file in the same place (the same scenes, estimated under
two settings; ``eval_accuracy.py --out`` writes them). Prints, per pair, both runs' positional error of the
best pose, mean (median) cm over the scenes, and the mean per-scene difference (other minus base) with its
bootstrap 90 % interval (``--resamples`` draws of the scenes, seed 0); then the same pooled over the scenes
of each ``--groups`` label (one per pair; all pairs in one group without it). A difference whose interval
holds 0 is within what the scenes' draw alone moves. Reads the files only.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def best_position_cm(path: str) -> np.ndarray:
    """(S,) cm: the best pose's positional error per scene of an ``eval_accuracy.py --out`` file (``position``,
    (S, K) m, best first)."""
    with np.load(path) as data:
        return 100.0 * np.asarray(data["position"], dtype=np.float64)[:, 0]


def paired_difference(base: np.ndarray, other: np.ndarray, resamples: int, rng: np.random.Generator
                      ) -> tuple[float, float, float]:
    """Mean of other - base (S,) and its bootstrap 90 % interval (5th, 95th percentile of the mean over
    ``resamples`` draws of S scenes with replacement). Scenes where either is NaN (no estimate) are left out."""
    difference = np.asarray(other, dtype=np.float64) - np.asarray(base, dtype=np.float64)
    difference = difference[np.isfinite(difference)]
    if len(difference) == 0:
        raise SystemExit("no scene has an estimate in both runs")
    draws = rng.integers(0, len(difference), (resamples, len(difference)))
    means = difference[draws].mean(axis=1)
    return float(difference.mean()), float(np.percentile(means, 5)), float(np.percentile(means, 95))


def summary(values: np.ndarray) -> str:
    return f"{np.nanmean(values):.2f} ({np.nanmedian(values):.2f})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", nargs="+", required=True, help="eval_accuracy.py --out files, the reference run")
    parser.add_argument("--other", nargs="+", required=True, help="the same scenes under the setting compared")
    parser.add_argument("--groups", nargs="+", help="a label per pair, to pool over (e.g. the scene set)")
    parser.add_argument("--resamples", type=int, default=4000)
    args = parser.parse_args(argv)
    groups = args.groups or ["all"] * len(args.base)
    if not len(args.base) == len(args.other) == len(groups):
        raise SystemExit(f"{len(args.base)} --base, {len(args.other)} --other and {len(groups)} --groups: "
                         "one of each per pair")
    pooled: dict[str, tuple[list, list]] = {}
    for base_path, other_path, group in zip(args.base, args.other, groups):
        base, other = best_position_cm(base_path), best_position_cm(other_path)
        if base.shape != other.shape:
            raise SystemExit(f"{base_path} has {len(base)} scenes, {other_path} {len(other)}: not the same scenes")
        mean, low, high = paired_difference(base, other, args.resamples, np.random.default_rng(0))
        print(f"{other_path} against {base_path}: {summary(other)} cm against {summary(base)}, "
              f"per scene {mean:+.3f} cm [{low:+.3f}, {high:+.3f}]")
        pooled.setdefault(group, ([], []))[0].append(base)
        pooled[group][1].append(other)
    for group, (bases, others) in pooled.items():
        base, other = np.concatenate(bases), np.concatenate(others)
        mean, low, high = paired_difference(base, other, args.resamples, np.random.default_rng(0))
        print(f"{group}: {len(base)} scenes, {summary(other)} cm against {summary(base)}, "
              f"per scene {mean:+.3f} cm [{low:+.3f}, {high:+.3f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
