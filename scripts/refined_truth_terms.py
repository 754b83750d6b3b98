"""Does the refinement move the true pose away from where its presses match the images? One sequence's frames.

    python scripts/refined_truth_terms.py --artifacts ART --sequence 4 --frames 0 5 10 20 [override ...]

On frames of one sequence of ``ART/sequences/tracking.h5``, read through the *true* sensor poses (the reported ones
with the bias the sequence drew taken out: no kinematic error left), the true object pose is scored term by term
(surface fit, penetration, sensor corrections, render-and-compare; ``scripts/oracle_corrections.py``'s terms) as it
stands (``rank.score_refined``, no correction) and as the ranking re-scores a candidate (``rank.refine_and_score``,
the tracker's refinement steps), with how far the refinement moved it. A refined truth that scores worse than the
truth itself means the refinement's own objective (contact points, normals, patch points) pulls away from what the
images show: the diagnosis behind ``rank.refine_patch_normal_weight`` (docs/contact_patch.md). A diagnostic: it
changes nothing and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from oracle_corrections import TERMS, score_terms  # noqa: E402  (scripts/, this script's folder)

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.geometry import invert_pose, make_pose, rotvec_to_rotmat  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation import rank as rank_step  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--sequence", type=int, required=True, help="index of the sequence in tracking.h5")
    parser.add_argument("--frames", type=int, nargs="+", default=[0], help="frame indices")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    seq = read_artifact(layout.sequences_file(args.artifacts, "tracking"), "sequences")
    q = args.sequence
    est = Estimator.from_artifacts(str(seq["objects"][q]), args.artifacts, cfg)
    settings = est.settings
    T, images, truth = (np.asarray(seq[k][q]) for k in ("T_world_sensors", "images", "T_world_object"))
    bias = make_pose(rotvec_to_rotmat(np.asarray(seq["pose_bias_rotvec"][q])), np.asarray(seq["pose_bias_translation"][q]))
    T_true = T @ invert_pose(bias)  # each sensor's reported pose with its drawn bias taken out
    print(f"{seq['names'][q]}: the true pose through the true sensor poses, score terms in mm")
    for f in args.frames:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            contacts = est.contacts(T_true[f], images[f])
        fit, _, _ = rank_step.touching_fit(est.surface, contacts, settings.rank)
        seen = np.repeat(truth[f][None, None], len(contacts.points), axis=1)  # no corrections
        as_is = rank_step.score_refined(est.penetration_model, fit, est.mesh, truth[f][None], seen, T_true[f], contacts,
                                        settings.rank, settings.sensors)
        refined = rank_step.refine_and_score(est.penetration_model, est.surface, est.mesh, truth[f][None], T_true[f],
                                             contacts, settings.rank, settings.sensors, int(cfg.track.refine_iterations))
        for name, scored in (("as it is", as_is), ("refined", refined)):
            terms = score_terms(scored, settings.rank, settings.sensors)[0]
            moved = 100 * np.linalg.norm(scored.poses[0][:3, 3] - truth[f][:3, 3])
            print(f"  frame {f:3d} {name:9s}" + "".join(f" {t} {1000 * v:.3f}" for t, v in zip(TERMS, terms))
                  + f"; score {1000 * scored.scores[0]:.3f}; moved {moved:.2f} cm")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
