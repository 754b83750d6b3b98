"""Why does a wrong pose win the ranking? Each scene's refined candidates, scored term by term against the truth.

    python scripts/rank_terms.py --artifacts artifacts --scenes kinematic validation [override ...]

Estimates every scene of the sets with the default estimator (as stage rank does, images and each sensor's
no-contact image) and records, for each of the ``rank.candidates`` candidates that ranking re-scores, the
terms of its score (``tactile6d.estimation.rank.rank``): surface loss ``d + w_n * a`` (``RankSettings.surface_normal_weight``),
penetration cost, ``pose_correction_weight`` x the sensor corrections' cost and ``agreement_weight`` x the
render-and-compare cost. For each scene whose winner is more than ``--wrong-cm`` from the true position, it
prints the candidate nearest the truth, its place in the ranking and by how much each term favoured the
winner over it; then, per set, the mean of those differences. A diagnostic: it reads the terms by wrapping
the rank module's functions for the duration of the run, and changes no estimate.

``--against-truth``: for every scene, the winner and the true pose are each re-scored alone as the ranking
re-scores a candidate (refined, then scored term by term), and the terms of the two compared: per set, over
the scenes where the refined truth scores worse, how much each term favours the winner (mean, median, and in
how many scenes). Where the winner is near the truth anyway, this says which term keeps the best pose off it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

import tactile6d.estimation.rank as rank_module  # noqa: E402
from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

TERMS = ("surface", "penetration", "correction", "agreement")


class Recorder:
    """Wraps the functions ``rank.rank`` scores with and keeps what they returned for the last estimate."""

    def __init__(self):
        self.last: dict = {}
        self._saved = {}

    def _wrap(self, owner, name, key, keep_all=False):
        original = getattr(owner, name)
        self._saved[(owner, name)] = original

        def wrapper(*args, **kwargs):
            out = original(*args, **kwargs)
            if key == "candidates":
                self.last[key] = np.array(args[0])
            elif keep_all:
                self.last.setdefault(key, []).append(out)
            else:
                self.last[key] = out
            return out
        setattr(owner, name, wrapper)

    def __enter__(self):
        self._wrap(rank_module, "penetration_cost", "penetration", keep_all=True)
        self._wrap(rank_module, "agreement_cost", "agreement")
        self._wrap(rank_module, "distinct_in_order", "candidates")
        self._wrap(rank_module.refinement, "sensor_corrections_cost", "correction")
        self._wrap(rank_module.refinement, "surface_losses", "surface")
        return self

    def __exit__(self, *exc):
        for (owner, name), original in self._saved.items():
            setattr(owner, name, original)


def normal_weight_of(estimator: Estimator, contacts) -> float:
    """m/rad: the weight the ranking gave these contacts' normals (``RankSettings.surface_normal_weight``)."""
    settings = estimator.settings.rank
    return settings.surface_normal_weight(rank_module.fits_patch_points(contacts, settings))


def scene_terms(last: dict, rank_cfg, normal_weight: float) -> dict[str, np.ndarray]:
    """The recorded calls of one estimate -> each re-scored candidate's weighted score terms (m), in the
    candidates' order; normal_weight (m/rad) that of ``normal_weight_of``."""
    distance, angle = last["surface"]
    n = len(distance)
    zero = np.zeros(n)
    return {
        "surface": distance + float(normal_weight) * angle,
        "penetration": np.asarray(last["penetration"][-1]),  # the last call scores the refined candidates
        "correction": float(rank_cfg.pose_correction_weight) * np.asarray(last.get("correction", zero)),
        "agreement": float(rank_cfg.agreement_weight) * np.asarray(last.get("agreement", zero)),
    }


def rescored_terms(estimator: Estimator, T_world_sensors: np.ndarray, pose: np.ndarray, contacts, rank_cfg
                   ) -> tuple[dict[str, float], np.ndarray]:
    """One pose (4, 4) re-scored alone as the ranking re-scores a candidate -> (its weighted terms (m), the
    refined pose (4, 4))."""
    with Recorder() as recorder:
        ranked = estimator.rank(T_world_sensors, np.asarray(pose)[None], np.zeros(1), contacts)
    terms = scene_terms(recorder.last, rank_cfg, normal_weight_of(estimator, contacts))
    return {t: float(v[0]) for t, v in terms.items()}, ranked.poses[0]


def favoured(differences: list[dict[str, float]]) -> str:
    """Per term, over winner-minus-truth differences (mm): mean, median and how many favour the winner (< 0)."""
    parts = []
    for t in TERMS:
        values = np.array([d[t] for d in differences])
        parts.append(f"{t} {values.mean():+.2f} (median {np.median(values):+.2f}, {int((values < 0).sum())} scenes)")
    return ", ".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", required=True, help="scene sets (artifacts/scenes/<set>.h5)")
    parser.add_argument("--wrong-cm", type=float, default=1.0, help="a winner this far from the truth is wrong")
    parser.add_argument("--against-truth", action="store_true",
                        help="also re-score the winner and the true pose alone and compare their terms, every scene")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    if not (cfg.rank.refine or cfg.rank.agreement_weight > 0):
        raise SystemExit("ranking re-scores no candidate with these settings (rank.refine off, no agreement)")
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        estimators, wrong, truth_worse = {}, [], []
        for s in range(len(scenes["names"])):
            obj = str(scenes["objects"][s])
            if obj not in estimators:
                estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
            T = scenes["T_world_sensors"][s]
            with Recorder() as recorder:
                estimate = estimators[obj].estimate(T, scenes["images"][s], scene_backgrounds(scenes, s))
            terms = scene_terms(recorder.last, cfg.rank, normal_weight_of(estimators[obj], estimate.contacts))
            if args.against_truth:
                truth = np.asarray(scenes["T_world_object"][s])
                mine, _ = rescored_terms(estimators[obj], T, estimate.best, estimate.contacts, cfg.rank)
                theirs, refined = rescored_terms(estimators[obj], T, truth, estimate.contacts, cfg.rank)
                if sum(mine.values()) < sum(theirs.values()):
                    truth_worse.append({t: 1000 * (mine[t] - theirs[t]) for t in TERMS})
                print(f"{scene_set} {s:3d} {obj:22s} winner {100 * np.linalg.norm(estimate.best[:3, 3] - truth[:3, 3]):.2f} "
                      f"cm, refined truth {100 * np.linalg.norm(refined[:3, 3] - truth[:3, 3]):.2f} cm; winner minus "
                      "truth (mm): " + ", ".join(f"{t} {1000 * (mine[t] - theirs[t]):+.2f}" for t in TERMS))
            score = sum(terms.values())
            position = np.linalg.norm(recorder.last["candidates"][:, :3, 3] - scenes["T_world_object"][s][:3, 3], axis=1)
            order = np.lexsort((np.arange(len(score)), score))
            winner, nearest = int(order[0]), int(np.argmin(position))
            if position[winner] * 100 <= args.wrong_cm:
                continue
            diff = {t: 1000 * (terms[t][winner] - terms[t][nearest]) for t in TERMS}
            wrong.append(diff)
            print(f"{scene_set} {s:3d} {obj:22s} winner {100 * position[winner]:.2f} cm; nearest candidate "
                  f"{100 * position[nearest]:.2f} cm, ranked {int(np.flatnonzero(order == nearest)[0]) + 1} of {len(score)}; "
                  "winner minus nearest (mm): " + ", ".join(f"{t} {v:+.2f}" for t, v in diff.items()))
        summary = ", ".join(f"{t} {np.mean([d[t] for d in wrong]):+.2f}" for t in TERMS) if wrong else "-"
        print(f"{scene_set}: {len(wrong)} of {len(scenes['names'])} winners over {args.wrong_cm:g} cm; mean winner "
              f"minus nearest (mm): {summary}")
        if args.against_truth:
            print(f"{scene_set}: the refined truth scores worse than the winner in {len(truth_worse)} of "
                  f"{len(scenes['names'])}; there, winner minus truth (mm): "
                  + (favoured(truth_worse) if truth_worse else "-"))
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
