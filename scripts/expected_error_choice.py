"""Would reporting the pose of least expected positional error, rather than the best-scored one, help?

    python scripts/expected_error_choice.py --artifacts artifacts --scenes validation offaxis variation kinematic \
        [--tau 0.1 0.2 0.3] [override ...]

Each scene is estimated as stage rank does, keeping every distinct refined candidate (``rank.top_k`` raised
to ``rank.candidates``). Read as a posterior, exp(-(score - best score) / tau) over them, the pose that
minimises the expected distance of its origin to theirs (``expected_error_choice``) is the Bayes choice for
the positional error: where several poses explain the contacts alike (a pitcher turned about its body), it
takes the one amid them rather than whichever scored a hair better. Per set and tau it prints the positional
error #1 of the best-scored pose and of that choice, mean (median) cm, their mean difference per scene with
a 90 % bootstrap interval, and how often the choice is not the best-scored pose. A diagnostic: it changes
nothing and writes nothing (docs/real_sensors.md: measured, not adopted).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def expected_error_choice(translations: np.ndarray, scores: np.ndarray, tau: float) -> int:
    """Index of the pose whose origin is nearest, in expectation, to the others': translations (K, 3) m, scores
    (K,) m (lower better), tau m > 0 -> argmin_i sum_j w_j ||t_i - t_j||, w_j proportional to
    exp(-(score_j - min score) / tau). A tau far below the scores' gaps gives the best-scored pose."""
    t, s = np.asarray(translations, dtype=np.float64), np.asarray(scores, dtype=np.float64)
    w = np.exp(-(s - s.min()) / tau)
    distances = np.linalg.norm(t[:, None] - t[None], axis=-1)
    return int(np.argmin(distances @ (w / w.sum())))


def bootstrap_interval(differences: np.ndarray, level: float = 0.9, n: int = 2000, seed: int = 0) -> tuple[float, float]:
    """The mean's bootstrap interval of per-scene differences (S,) at ``level``."""
    rng = np.random.default_rng(seed)
    d = np.asarray(differences, dtype=np.float64)
    means = d[rng.integers(0, len(d), (n, len(d)))].mean(axis=1)
    return float(np.quantile(means, (1 - level) / 2)), float(np.quantile(means, (1 + level) / 2))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", required=True, help="scene sets (artifacts/scenes/<set>.h5)")
    parser.add_argument("--tau", type=float, nargs="+", default=[0.1, 0.2, 0.3], help="mm of score")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    cfg = compose_config([*args.overrides, f"rank.top_k={int(cfg.rank.candidates)}"])
    estimators: dict[str, Estimator] = {}
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        best, chosen = [], {tau: [] for tau in args.tau}
        for s in range(len(scenes["names"])):
            obj = str(scenes["objects"][s])
            if obj not in estimators:
                estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                estimate = estimators[obj].estimate(scenes["T_world_sensors"][s], scenes["images"][s],
                                                    scene_backgrounds(scenes, s))
            truth = np.asarray(scenes["T_world_object"][s])[:3, 3]
            errors = 100 * np.linalg.norm(estimate.poses[:, :3, 3] - truth, axis=1)
            best.append(errors[0])
            for tau in args.tau:
                i = expected_error_choice(estimate.poses[:, :3, 3], estimate.scores, tau / 1000)
                chosen[tau].append((errors[i], i != 0))
        best = np.array(best)
        print(f"{scene_set}: {len(best)} scenes; best-scored pose {best.mean():.2f} cm (median {np.median(best):.2f})")
        for tau in args.tau:
            errors = np.array([e for e, _ in chosen[tau]])
            low, high = bootstrap_interval(errors - best)
            moved = np.mean([m for _, m in chosen[tau]])
            print(f"  tau {tau:g} mm: {errors.mean():.2f} cm (median {np.median(errors):.2f}), "
                  f"{(errors - best).mean():+.3f} cm per scene [{low:+.3f}, {high:+.3f}], another pose in "
                  f"{100 * moved:.0f} %", flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
