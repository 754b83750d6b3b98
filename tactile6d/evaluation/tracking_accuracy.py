"""How well a track follows the object: per-frame errors, the time spent lost, recovery, and the same
frames estimated from scratch beside it (stage evaluate_tracking, ``tactile6d bench track``).

Per frame, the positional error ``||t_est - t_gt||`` and the ADI (``core.metrics``) of the pose the tracker
returned. Over a sequence:

- ``longest_over``: the longest stretch of consecutive frames whose positional error exceeds a threshold,
  in seconds (frames / fps): how long the track stays wrong before it recovers;
- ``frames_to_recover``: after an event at frame e (a jump, a swap), the frames until the error is back
  under a threshold.

Single-shot estimation is compared on a subsample of the same frames (every ``single_shot_every``-th),
since it costs 0.4 s per frame; medians over "the same frames" are taken on that subsample.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from tactile6d.core import metrics


def true_runs(flags: np.ndarray) -> np.ndarray:
    """The runs of True in a (F,) bool array, in order: (R, 2) int, each row [start, stop) in frames."""
    padded = np.concatenate([[False], np.asarray(flags, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return np.stack([edges[::2], edges[1::2]], axis=1)


def run_lengths(flags: np.ndarray) -> np.ndarray:
    """Lengths (R,) of the runs of True in a (F,) bool array, in order (empty when there is none)."""
    runs = true_runs(flags)
    return runs[:, 1] - runs[:, 0]


def longest_over(errors: np.ndarray, threshold: float, fps: float) -> float:
    """Seconds of the longest run of consecutive frames with error > threshold: errors (F,) m, NaN counting
    as over (no pose); fps frames per second. 0 when no frame is over."""
    errors = np.asarray(errors, dtype=np.float64)
    runs = run_lengths(~(errors <= threshold))
    return float(runs.max() / fps) if runs.size else 0.0


def frames_to_recover(errors: np.ndarray, event: int, threshold: float) -> int | None:
    """Frames from ``event`` (the first frame after a jump or swap) to the first whose error (m) is under
    ``threshold`` and stays under it for the rest of the run given: 0 when the event's frame is already
    right; None when it never recovers. errors (F,) m."""
    errors = np.asarray(errors, dtype=np.float64)[event:]
    bad = np.flatnonzero(~(errors <= threshold))
    if bad.size == 0:
        return 0
    return None if bad[-1] == len(errors) - 1 else int(bad[-1] + 1)


def pose_errors(model_points: np.ndarray, poses: np.ndarray, truth: np.ndarray, tree=None) -> dict[str, np.ndarray]:
    """Per-frame errors of poses (F, 4, 4) against truth (F, 4, 4): ``position`` and ``adi`` (F,) m, NaN
    where a pose is NaN (no pose yet). model_points (N, 3) object frame."""
    poses, truth = np.asarray(poses, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    out = {"position": np.full(len(poses), np.nan), "adi": np.full(len(poses), np.nan)}
    tree = metrics.model_tree(model_points) if tree is None else tree
    for f in np.flatnonzero(np.isfinite(poses).all(axis=(1, 2))):
        out["position"][f] = metrics.positional_error(poses[f], truth[f])
        out["adi"][f] = metrics.adi(model_points, poses[f], truth[f], tree)
    return out


def track_frames(update: Callable, T_world_sensors: np.ndarray, images: np.ndarray, backgrounds=None,
                 progress: Callable | None = None) -> list:
    """``update(T (L, 4, 4), images (L, 320, 240, 3), backgrounds)`` (``Tracker.update``) over the frames
    T_world_sensors (F, L, 4, 4), images (F, L, 320, 240, 3) in order -> the F answers."""
    out = []
    for f in range(len(T_world_sensors)):
        out.append(update(T_world_sensors[f], images[f], backgrounds))
        if progress is not None:
            progress()
    return out


def summarise_sequence(track: dict[str, np.ndarray], single: dict[str, np.ndarray], compared: np.ndarray,
                       modes: Sequence[str], seconds: np.ndarray, fps: float, lost_threshold: float) -> dict:
    """One sequence's figures, centimetres and seconds.

    track: the tracker's per-frame errors (``pose_errors``, F frames); single: single-shot errors on the
    ``compared`` frames (C,) indices, NaN where the estimate failed (counted in ``single_failed``, left out of the
    medians and means); modes (F,) the tracker's ``TrackedFrame.mode``; seconds (F,) its
    wall-clock time per frame; lost_threshold (m): the error over which a frame counts as lost.
    """
    position = np.asarray(track["position"], dtype=np.float64)
    updates = np.asarray([m == "update" for m in modes])
    return {
        "frames": int(len(position)),
        "track_position_cm_median": 100 * float(np.nanmedian(position)),
        "track_position_cm_mean": 100 * float(np.nanmean(position)),
        "track_position_cm_max": 100 * float(np.nanmax(position)),
        "track_adi_cm_median": 100 * float(np.nanmedian(track["adi"])),
        "compared_frames": int(len(compared)),
        "track_position_cm_median_compared": 100 * float(np.nanmedian(position[compared])),
        "single_position_cm_median": 100 * float(np.nanmedian(single["position"])),
        "single_position_cm_mean": 100 * float(np.nanmean(single["position"])),
        "single_failed": int(np.isnan(single["position"]).sum()),
        "longest_over_s": longest_over(position, lost_threshold, fps),
        "redetections": int(sum(m == "redetect" for m in modes)),
        "held": int(sum(m == "hold" for m in modes)),
        "update_ms_median": 1e3 * float(np.median(np.asarray(seconds)[updates])) if updates.any() else float("nan"),
    }


def trust_summary(ambiguous: np.ndarray, confidence: np.ndarray, adi: np.ndarray, threshold: float = 0.01) -> dict:
    """How the tracker's per-frame trust signals sort its frames. ambiguous (F,) bool (``TrackedFrame.ambiguous``),
    confidence (F,) (NaN where there was none), adi (F,) m -> the share of frames flagged ambiguous, the share
    of flagged and of unflagged frames whose ADI is ``threshold`` or more (NaN where there are none), and the
    confidence's AUROC for ADI under ``threshold`` over the frames that have one (NaN when one class is absent)."""
    flagged = np.asarray(ambiguous, dtype=bool)
    adi, p = np.asarray(adi, dtype=np.float64), np.asarray(confidence, dtype=np.float64)
    wrong = ~(adi < threshold)  # a frame without a pose counts as wrong
    known = np.isfinite(p)
    return {
        "ambiguous_share": float(flagged.mean()) if len(flagged) else float("nan"),
        "wrong_share_ambiguous": float(wrong[flagged].mean()) if flagged.any() else float("nan"),
        "wrong_share_unambiguous": float(wrong[~flagged].mean()) if (~flagged).any() else float("nan"),
        "confidence_auroc": metrics.auroc(p[known & ~wrong], p[known & wrong]),
    }


def summarise_set(per_sequence: list[dict], track_position: np.ndarray, single_position: np.ndarray,
                  track_position_compared: np.ndarray) -> dict:
    """The whole set's figures from its sequences' (``summarise_sequence``) and the pooled per-frame
    positional errors (m): every frame tracked, the compared frames single-shot, and the tracker on those."""
    return {
        "sequences": len(per_sequence),
        "frames": int(sum(s["frames"] for s in per_sequence)),
        "track_position_cm_median": 100 * float(np.nanmedian(track_position)),
        "track_position_cm_mean": 100 * float(np.nanmean(track_position)),
        "track_position_cm_median_compared": 100 * float(np.nanmedian(track_position_compared)),
        "single_position_cm_median": 100 * float(np.nanmedian(single_position)),
        "single_position_cm_mean": 100 * float(np.nanmean(single_position)),
        "single_failed": int(np.isnan(single_position).sum()),
        "longest_over_s_max": max(s["longest_over_s"] for s in per_sequence),
        "redetections": int(sum(s["redetections"] for s in per_sequence)),
        "update_ms_median": float(np.nanmedian([s["update_ms_median"] for s in per_sequence])),
    }
