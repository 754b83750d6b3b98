"""Does a hand's sensor bias, known or learned over the frames, let a sequence's frames tell the truth from a wrong pose?

    python scripts/sequence_bias.py --artifacts ART --sequence 5 [--every 3] [--rounds 12] [override ...]

The generated sequences' sensor poses carry a hand's kinematic error, mostly a bias per sensor drawn once per
sequence (``tactile6d.sim.sequences``). Frame by frame, the tracker scores its poses through the sensor poses as
reported, each sensor's error taken up by a correction that pays the declared prior (``sensors.pose_sigma_*``)
anew every frame. On one sequence of ``ART/sequences/tracking.h5`` this script runs the tracker
(``Tracker.update``, default settings) until it follows a pose over ``--lost`` cm off; that *wrong* pose is then
carried beside the truth, fixed to it in the object's frame. Every ``--every``-th frame both are refined and
scored as the tracker scores them (``rank.refine_and_score``):

- *as reported*: through the sensor poses as given, the declared prior (what the tracker does);
- *true bias* (the truth only): through the sensor poses corrected by the bias the sequence drew, with a prior of
  ``--tight`` mm and deg left for the per-frame jitter: what a calibrated hand would give;
- *learned*: through sensor poses corrected by a bias learned from the frames themselves, each pose its own:
  ``--rounds`` rounds of refining every frame with the declared prior times ``--loose``, averaging the sensors'
  corrections over the frames (sensor frames) and composing the mean into the bias; scored as for the true bias.

It prints, per pose and way, the mean over frames of the score and of its data terms (surface fit, penetration,
render-and-compare: all but the corrections' cost), mm. Where the learned bias gives the truth lower data terms
than the wrong pose, a tracker that learned each pose's bias could tell them apart; where it does not, the
frames' contacts and images prefer the wrong pose whatever the bias. A diagnostic: it changes nothing and
writes nothing (docs/tracking.md, What the misses come from).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.geometry import invert_pose, make_pose, rotmat_to_rotvec, rotvec_to_rotmat  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation import rank as rank_step  # noqa: E402
from tactile6d.estimation import refine as refinement  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.optimize import use_cpu_devices_for  # noqa: E402
from tactile6d.estimation.tracker import Tracker, TrackSettings  # noqa: E402
from tactile6d.perception.contacts import Contacts  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def contacts_through(contacts: Contacts, T_from: np.ndarray, T_to: np.ndarray) -> Contacts:
    """The contacts read through sensor poses T_from (L, 4, 4), as read through T_to (L, 4, 4) instead: each
    sensor's point and normal moved with it (the patches, in the sensor's frame, unchanged)."""
    W = np.asarray(T_to, dtype=np.float64) @ invert_pose(T_from)
    points = np.einsum("lab,lb->la", W[:, :3, :3], contacts.points) + W[:, :3, 3]
    normals = np.einsum("lab,lb->la", W[:, :3, :3], contacts.normals)
    return replace(contacts, points=points, normals=normals)


def sensor_corrections(T: np.ndarray, pose: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Each sensor's pose error in its own frame (L, 4, 4) that a refinement's corrections imply: the object at
    ``pose`` (4, 4) seen by sensor i at ``seen[i]`` (L, 4, 4, as ``refine.refine_poses_and_sensors`` gives it)
    through sensor poses T (L, 4, 4) means the sensor is truly at ``T[i] @ correction[i]``."""
    return invert_pose(T) @ np.asarray(pose)[None] @ invert_pose(seen) @ np.asarray(T)


def mean_motion(motions: np.ndarray) -> np.ndarray:
    """Small motions (F, L, 4, 4) averaged over F -> (L, 4, 4): the mean rotation vector and translation."""
    motions = np.asarray(motions, dtype=np.float64)
    rotvecs = rotmat_to_rotvec(motions[..., :3, :3].reshape(-1, 3, 3)).reshape(motions.shape[:2] + (3,))
    return make_pose(rotvec_to_rotmat(rotvecs.mean(axis=0)), motions[..., :3, 3].mean(axis=0))


def data_terms(scored: rank_step.RefinedScores, rank, sensors) -> np.ndarray:
    """(P,) m: the score less the corrections' cost: surface fit, penetration and render-and-compare."""
    from oracle_corrections import TERMS, score_terms  # scripts/, this script's folder

    data = [i for i, term in enumerate(TERMS) if term != "corrections"]
    return score_terms(scored, rank, sensors)[:, data].sum(axis=1)


class Sequence:
    """The frames ``frames`` of one sequence as the estimator reads them: the sensor poses as reported T
    (F, L, 4, 4) and each frame's contacts through them (images (F, L, 320, 240, 3)); scored with the
    tracker's ``iterations`` refinement steps."""

    def __init__(self, estimator: Estimator, T: np.ndarray, images: np.ndarray, frames: list[int], iterations: int):
        self.estimator, self.T, self.frames, self.iterations = estimator, T, frames, iterations
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.contacts = {f: estimator.contacts(T[f], images[f]) for f in frames}

    def score(self, poses: dict[int, np.ndarray], correction: np.ndarray, sensors) -> tuple[float, float]:
        """Mean over frames (m) of the score and of its data terms of ``poses[f]`` refined through the sensor
        poses ``T[f] @ correction`` (correction (L, 4, 4), sensor frames) with the ``sensors`` prior."""
        est, scores, data = self.estimator, [], []
        for f in self.frames:
            T = self.T[f] @ correction
            scored = rank_step.refine_and_score(est.penetration_model, est.surface, est.mesh, poses[f][None], T,
                                                contacts_through(self.contacts[f], self.T[f], T), est.settings.rank,
                                                sensors, self.iterations)
            scores.append(scored.scores[0])
            data.append(data_terms(scored, est.settings.rank, sensors)[0])
        return float(np.mean(scores)), float(np.mean(data))

    def learn_bias(self, poses: dict[int, np.ndarray], sensors, rounds: int) -> np.ndarray:
        """A bias (L, 4, 4) learned for ``poses``: each round every frame refined through the sensors corrected
        so far with the ``sensors`` prior, the corrections it implies averaged over the frames and composed in."""
        est, rank = self.estimator, self.estimator.settings.rank
        bias = np.repeat(np.eye(4)[None], self.T.shape[1], axis=0)
        for _ in range(rounds):
            implied = []
            for f in self.frames:
                T = self.T[f] @ bias
                # rank.refine_and_score's refinement, written out: it does not return the corrections (seen).
                fit, touched, on = rank_step.touching_fit(est.surface, contacts_through(self.contacts[f], self.T[f], T), rank)
                points, owners = touched.patch_points(T[on], int(rank.refine_patch_points))
                weights = rank_step._per_sensor_weights(owners, len(on), float(rank.refine_patch_weight))
                refined, seen = refinement.refine_poses_and_sensors(
                    fit, poses[f][None], *sensors.correction_sigmas, n_iterations=8, patch_points=points,
                    patch_weights=weights, patch_owners=owners)
                correction = np.repeat(np.eye(4)[None], len(T), axis=0)
                correction[on] = sensor_corrections(T[on], refined[0], seen[0])
                implied.append(correction)
            bias = bias @ mean_motion(np.array(implied))
        return bias


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--sequence", type=int, required=True, help="index of the sequence in tracking.h5")
    parser.add_argument("--every", type=int, default=3, help="score every N-th frame")
    parser.add_argument("--rounds", type=int, default=12, help="rounds of learning each pose's bias")
    parser.add_argument("--loose", type=float, default=2.0, help="the declared prior's scale while learning")
    parser.add_argument("--tight", type=float, default=0.3, help="mm and deg: the prior left once the bias is taken out")
    parser.add_argument("--lost", type=float, default=2.0, help="cm: a followed pose this far off is the wrong one")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    seq = read_artifact(layout.sequences_file(args.artifacts, "tracking"), "sequences")
    q = args.sequence
    estimator = Estimator.from_artifacts(str(seq["objects"][q]), args.artifacts, cfg)
    T, images, truth = (np.asarray(seq[k][q]) for k in ("T_world_sensors", "images", "T_world_object"))
    drawn = make_pose(rotvec_to_rotmat(np.asarray(seq["pose_bias_rotvec"][q])), np.asarray(seq["pose_bias_translation"][q]))

    wrong_in_object = None
    with Tracker(estimator, TrackSettings.from_cfg(cfg.track)) as tracker, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for f in range(len(T)):
            tracker.update(T[f], images[f])
            lost = [h.poses[-1] for h in tracker._hypotheses
                    if 100 * np.linalg.norm(h.poses[-1][:3, 3] - truth[f][:3, 3]) > args.lost]
            if lost:
                wrong_in_object = invert_pose(truth[f]) @ lost[0]
                print(f"{seq['names'][q]}: a pose {100 * np.linalg.norm(lost[0][:3, 3] - truth[f][:3, 3]):.2f} cm off "
                      f"followed from frame {f}")
                break
    if wrong_in_object is None:
        print(f"{seq['names'][q]}: the tracker follows no pose over {args.lost} cm off")
        return 0

    frames = list(range(0, len(T), args.every))
    sequence = Sequence(estimator, T, images, frames, int(cfg.track.refine_iterations))
    declared = estimator.settings.sensors
    tight = replace(declared, pose_sigma_mm=args.tight, pose_sigma_deg=args.tight)
    loose = replace(declared, pose_sigma_mm=args.loose * declared.pose_sigma_mm,
                    pose_sigma_deg=args.loose * declared.pose_sigma_deg)
    identity = np.repeat(np.eye(4)[None], T.shape[1], axis=0)
    poses = {"truth": {f: truth[f] for f in frames}, "wrong": {f: truth[f] @ wrong_in_object for f in frames}}
    print(f"{len(frames)} frames; mean over them, mm: score (data terms)")
    for name, pose in poses.items():
        rows = [("as reported", identity, declared)]
        if name == "truth":
            rows.append(("true bias", invert_pose(drawn), tight))
        rows.append((f"learned, {args.rounds} rounds", sequence.learn_bias(pose, loose, args.rounds), tight))
        for label, correction, sensors in rows:
            score, data = sequence.score(pose, correction, sensors)
            print(f"  {name:5s} {label:18s} {1000 * score:.3f} ({1000 * data:.3f})", flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
