"""Stage evaluate_tracking: the tracker against single-shot estimation on the generated sequences (``tracking``).

Each sequence of ``artifacts/sequences/tracking.h5`` (stage make_sequences) is fed frame by frame to its
object's ``Tracker`` (config section ``track``), with the sensor poses as the hand reports them (with
``track.evaluation.true_sensor_poses``, the poses without the hand's kinematic error, for tracker and
single-shot estimates alike: what that error costs); every
``track.evaluation.single_shot_every``-th frame is also estimated from scratch (``Estimator.estimate``, the
default settings), to compare on the same frames. Writes ``artifacts/metrics/tracking.json``: the set's
figures, each sequence's, and the per-frame errors, modes and times (stage report draws the error over time
from them). Frame times are measured here beside other work (two worker processes); ``tactile6d bench track``
measures the speed on its own.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import replace

import numpy as np

from tactile6d.core.errors import NoMatch, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.estimation.tracker import Tracker, TrackSettings
from tactile6d.evaluation import scoring
from tactile6d.evaluation import tracking_accuracy as accuracy
from tactile6d.perception.contacts import UntouchedSensorWarning
from tactile6d.runtime.executor import executor_from_config, process_cache
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed


def _sequences(artifacts: str):
    return process_cache(("sequences", artifacts),
                         lambda: read_artifact(layout.sequences_file(artifacts, "tracking"), "sequences"))


def _estimator(cfg, obj: str) -> Estimator:
    return process_cache(("estimator", obj), lambda: Estimator.from_artifacts(obj, cfg.paths.artifacts_dir, cfg),
                         slot="estimator")


def single_shot(estimator: Estimator, T: np.ndarray, images: np.ndarray) -> np.ndarray:
    """The best pose (4, 4) of a frame estimated from scratch; NaN when it matches nothing (a failure, as
    evaluate counts it). A lifted sensor is left out as the estimator leaves it out; the frames' ``touching``
    are stored, so its warning is not repeated in the log."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UntouchedSensorWarning)
            return estimator.estimate(T, images).best
    except NoMatch:
        return np.full((4, 4), np.nan)


def run_task(kind: str, q: int, cfg) -> dict:
    """One sequence tracked (``kind`` "track") or its compared frames estimated from scratch ("single")
    -> poses (F or C, 4, 4), and for the track each frame's mode, reason, seconds and confidence."""
    art = _sequences(cfg.paths.artifacts_dir)
    obj = str(art["objects"][q])
    poses = "T_world_sensors_true" if cfg.track.evaluation.true_sensor_poses else "T_world_sensors"
    T, images = np.asarray(art[poses][q]), np.asarray(art["images"][q])
    estimator = _estimator(cfg, obj)
    if kind == "single":
        every = int(cfg.track.evaluation.single_shot_every)
        frames = np.arange(0, len(T), every)
        return {"poses": np.stack([single_shot(estimator, T[f], images[f]) for f in frames]), "frames": frames}
    # One thread per worker: two workers already share the two cores; threads never change a result.
    settings = replace(TrackSettings.from_cfg(cfg.track), threads=1)
    with Tracker(estimator, settings) as tracker:
        answers = accuracy.track_frames(tracker.update, T, images)
    return {"poses": np.stack([a.pose for a in answers]), "modes": [a.mode for a in answers],
            "reasons": [a.reason for a in answers], "seconds": np.array([a.seconds for a in answers]),
            "confidence": [a.confidence for a in answers], "ambiguous": [a.ambiguous for a in answers]}


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = cfg.paths.artifacts_dir
    art = read_artifact(layout.sequences_file(artifacts, "tracking"), "sequences")
    objects = [str(o) for o in art["objects"]]
    fps, lost = float(np.asarray(art["fps"]).reshape(-1)[0]), float(cfg.track.evaluation.lost_threshold)
    tasks = [(kind, q) for q in range(len(objects)) for kind in ("single", "track")]
    with executor_from_config(cfg, int(cfg.track.evaluation.workers)) as executor:
        results = executor.map(run_task, [k for k, _ in tasks], [q for _, q in tasks], [cfg] * len(tasks),
                               desc="track sequences")
    done = {task: result for task, result in zip(tasks, results)}
    references = {o: scoring.load_object_reference(artifacts, o) for o in dict.fromkeys(objects)}
    per_sequence, pooled = [], {"track": [], "single": [], "compared": [], "adi": [], "ambiguous": [], "confidence": []}
    frames_out = []
    for q, obj in enumerate(objects):
        ref, truth = references[obj], np.asarray(art["T_world_object"][q])
        track, single = done[("track", q)], done[("single", q)]
        compared = single["frames"]
        track_err = accuracy.pose_errors(ref.points, track["poses"], truth, ref.tree)
        single_err = accuracy.pose_errors(ref.points, single["poses"], truth[compared], ref.tree)
        row = accuracy.summarise_sequence(track_err, single_err, compared, track["modes"], track["seconds"], fps, lost)
        per_sequence.append({"name": str(art["names"][q]), "object": obj, **row})
        pooled["track"].append(track_err["position"])
        pooled["single"].append(single_err["position"])
        pooled["compared"].append(track_err["position"][compared])
        pooled["adi"].append(track_err["adi"])
        pooled["ambiguous"].append(np.asarray(track["ambiguous"], dtype=bool))
        pooled["confidence"].append(np.array([np.nan if c is None else c for c in track["confidence"]]))
        frames_out.append({"track_position_m": track_err["position"].tolist(),
                           "single_frames": compared.tolist(), "single_position_m": single_err["position"].tolist(),
                           "modes": track["modes"], "reasons": track["reasons"],
                           "seconds": np.round(track["seconds"], 4).tolist(), "confidence": track["confidence"],
                           "ambiguous": track["ambiguous"],
                           "touching": np.asarray(art["touching"][q]).tolist()})
    summary = accuracy.summarise_set(per_sequence, *(np.concatenate(pooled[k]) for k in ("track", "single", "compared")))
    summary.update(accuracy.trust_summary(*(np.concatenate(pooled[k]) for k in ("ambiguous", "confidence", "adi"))))
    summary.update(fps=fps, lost_threshold_cm=100 * lost)
    write_json(layout.metrics_file(artifacts, "tracking"), {"summary": summary, "sequences": per_sequence,
                                                            "frames": frames_out})
    print(f"tracking: {summary['frames']} frames in {summary['sequences']} sequences; positional error median "
          f"{summary['track_position_cm_median']:.2f} cm tracked (on the compared frames "
          f"{summary['track_position_cm_median_compared']:.2f}) vs {summary['single_position_cm_median']:.2f} "
          f"single-shot ({summary['single_failed']} failed); longest over {100 * lost:.0f} cm {summary['longest_over_s_max']:.2f} s; "
          f"{summary['redetections']} re-detections")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
