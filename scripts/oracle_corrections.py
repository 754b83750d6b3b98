"""What do the images say when the sensors' errors are known? The truth scored through its true corrections.

    python scripts/oracle_corrections.py --artifacts artifacts --scenes kinematic [override ...]

On a set whose sensor poses were made wrong on purpose (``pose_error_*`` in the scenes file, as ``kinematic``),
each scene is estimated with the default estimator (as stage rank runs it), and three poses are scored as the
ranking scores its refined candidates (``rank.score_refined``: surface fit, penetration, the corrections' cost,
render-and-compare, each sensor seeing the object through its correction):

- the *winner*, the estimate's best pose, as the estimate scored it;
- the *refined truth*, the true pose refined from zero corrections (``rank.refine_and_score``, the floor of
  ``pose_floor.py``);
- the *oracle*, the true pose seen through corrections equal to each sensor's true error
  (``kinematic_bound.seen_through_true_errors``), not refined: what the images show, reproduced exactly but
  for their own reading.

Per scene it prints the three scores, the two truths' terms and their render-and-compare costs (mean over
sensors of 1 - mask IoU plus the share of untouched gel pressed). Per set it prints how often the oracle beats
the winner, how often its *data terms* alone (all but the corrections' cost) do, and the terms' means. Where the data terms prefer the truth and the total does not, the
corrections' prior, the price of the error the hand made, is what makes the wrong pose win; where the oracle
beats the refined truth, the refinement did not find corrections as good as the true ones. A diagnostic: it
changes nothing and writes nothing.
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
from tactile6d.estimation import rank as rank_step  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.evaluation.kinematic_bound import seen_through_true_errors, true_sensor_poses  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

TERMS = ("surface", "penetration", "corrections", "render-and-compare")


def score_terms(scored: rank_step.RefinedScores, settings, sensors) -> np.ndarray:
    """(P, 4) m: each pose's score split into ``TERMS``; the corrections' part is what the other three leave
    of the score (``rank.score_refined`` adds exactly these four)."""
    penetration = rank_step.penetration_cost(scored.depths, sensors.contact_sigma)
    agreement = settings.agreement_weight * scored.agreement
    corrections = scored.scores - scored.losses - penetration - agreement
    return np.stack([scored.losses, penetration, corrections, agreement], axis=1)


def oracle_score(est: Estimator, truth: np.ndarray, T_reported: np.ndarray, T_true: np.ndarray, contacts
                 ) -> rank_step.RefinedScores:
    """The true pose (4, 4) scored through each sensor's true error as its correction (not refined)."""
    settings, sensors = est.settings.rank, est.settings.sensors
    if sensors.exact:
        raise SystemExit("the oracle's corrections are scored as corrections: needs sensors.pose_sigma_* > 0")
    fit, _, _ = rank_step.touching_fit(est.surface, contacts, settings)
    seen = seen_through_true_errors(truth, T_reported, T_true)[None]
    return rank_step.score_refined(est.penetration_model, fit, agreement_mesh(est, contacts), truth[None], seen,
                                   np.asarray(T_reported), contacts, settings, sensors)


def refined_truth(est: Estimator, truth: np.ndarray, T_reported: np.ndarray, contacts) -> rank_step.RefinedScores:
    """The true pose (4, 4) refined from zero corrections and scored, as the ranking re-scores a candidate."""
    settings = est.settings.rank
    return rank_step.refine_and_score(est.penetration_model, est.surface, agreement_mesh(est, contacts), truth[None],
                                      np.asarray(T_reported), contacts, settings, est.settings.sensors,
                                      int(settings.refine_iterations))


def agreement_mesh(est: Estimator, contacts):
    """The mesh render-and-compare scores against, as the ranking passes it: None when it is off or the
    contacts hold no observed patches."""
    return est.mesh if est.settings.rank.uses_agreement and contacts.observed else None


def split(terms: np.ndarray) -> str:
    """A score's ``TERMS`` (4,) m as 'a + b + c + d' in mm."""
    return " + ".join(f"{1000 * t:.3f}" for t in terms)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", required=True, help="scene sets with sensor-pose errors (kinematic)")
    parser.add_argument("--wrong-cm", type=float, default=1.0, help="a best pose this far from the truth is wrong")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        if true_sensor_poses(scenes, 0) is None:
            raise SystemExit(f"{scene_set}: its scenes store no sensor-pose errors (pose_error_*): nothing to know")
        estimators: dict[str, Estimator] = {}
        rows = []  # (wrong, winner score, refined truth score, oracle terms (4,))
        for s in range(len(scenes["names"])):
            obj = str(scenes["objects"][s])
            if obj not in estimators:
                estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
            est, truth = estimators[obj], np.asarray(scenes["T_world_object"][s])
            T = np.asarray(scenes["T_world_sensors"][s])
            estimate = est.estimate(T, scenes["images"][s], scene_backgrounds(scenes, s))
            refined = refined_truth(est, truth, T, estimate.contacts)
            oracle = oracle_score(est, truth, T, true_sensor_poses(scenes, s), estimate.contacts)
            terms = score_terms(oracle, est.settings.rank, est.settings.sensors)[0]
            refined_terms = score_terms(refined, est.settings.rank, est.settings.sensors)[0]
            error = float(100 * np.linalg.norm(estimate.best[:3, 3] - truth[:3, 3]))
            rows.append((error > args.wrong_cm, float(estimate.scores[0]), float(refined.scores[0]), terms))
            print(f"{scene_set} {s:3d} {obj:22s} best {error:6.2f} cm  score (mm): winner {1000 * rows[-1][1]:.3f}, "
                  f"refined truth {1000 * rows[-1][2]:.3f} = {split(refined_terms)}, oracle {1000 * terms.sum():.3f} = "
                  f"{split(terms)}; render-and-compare cost: refined truth {refined.agreement[0]:.3f}, oracle "
                  f"{oracle.agreement[0]:.3f}", flush=True)
        wrong = np.array([r[0] for r in rows])
        winner, truth_refined = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
        terms = np.stack([r[3] for r in rows])
        total, data = terms.sum(axis=1), terms.sum(axis=1) - terms[:, 2]
        print(f"{scene_set}: {len(rows)} scenes, {int(wrong.sum())} over {args.wrong_cm:g} cm. The oracle scores better "
              f"than the winner in {int((total < winner).sum())} (over {args.wrong_cm:g} cm: {int((total < winner)[wrong].sum())}"
              f" of {int(wrong.sum())}); its data terms alone in {int((data < winner).sum())} "
              f"({int((data < winner)[wrong].sum())} of {int(wrong.sum())}); it beats the refined truth in "
              f"{int((total < truth_refined).sum())}. Mean terms of the oracle (mm): "
              + ", ".join(f"{name} {1000 * v:.3f}" for name, v in zip(TERMS, terms.mean(axis=0)))
              + f"; mean score: winner {1000 * winner.mean():.3f}, refined truth {1000 * truth_refined.mean():.3f}")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
