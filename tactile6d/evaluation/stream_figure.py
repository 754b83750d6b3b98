"""The figure of a tracked stream (``tactile6d track --plot``): how the pose moved, where the tracker estimated from
scratch or held, and how far each frame can be trusted. For a look at a track that has no ground truth, as a real
hand's has none: a jump at a re-detection, a pose that wanders while the sensors stay, or a long ambiguous stretch
shows at a glance what the text output holds line by line.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tactile6d.core.geometry import rotation_angle  # noqa: E402
from tactile6d.evaluation.tracking_accuracy import true_runs  # noqa: E402


def poses_to_motion(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """poses (F, 4, 4) ``T_world_object``, NaN on a frame without one -> (offsets (F, 3) m, each position less the
    first pose's, in the world frame; turns (F,) rad, each rotation's angle from the first pose's), NaN where no pose."""
    poses = np.asarray(poses, dtype=np.float64)
    have = np.isfinite(poses).all(axis=(1, 2))
    offsets = np.full((len(poses), 3), np.nan)
    turns = np.full(len(poses), np.nan)
    if have.any():
        first = poses[np.argmax(have)]
        offsets[have] = poses[have, :3, 3] - first[:3, 3]
        turns[have] = rotation_angle(first[:3, :3], poses[have, :3, :3])
    return offsets, turns


def stream_figure(times: np.ndarray, poses: np.ndarray, modes: list[str], confidence: np.ndarray,
                  ambiguous: np.ndarray, touching: np.ndarray, title: str):
    """Three panels over time (s): the object's position relative to its first pose (mm, world x, y, z), its turn
    from its first pose (deg), and how many sensors touch with the frame's confidence (P(ADI < 1 cm), when the
    estimator has a confidence model). Re-detections are red ticks at the top of each panel, held frames grey ones,
    ambiguous frames (another pose followed explains them about as well) shaded.

    times (F,) s; poses (F, 4, 4), NaN where a frame has no pose; modes (F,) ``TrackedFrame.mode``; confidence (F,),
    NaN where none; ambiguous (F,) bool; touching (F,) int, the sensors whose image shows contact.
    """
    times = np.asarray(times, dtype=np.float64)
    offsets, turns = poses_to_motion(poses)
    modes = np.asarray(modes)
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 6.2), sharex=True)
    position, turn, trust = axes
    for k, (axis, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        position.plot(times, 1000 * offsets[:, k], color=colour, lw=1.2, label=axis)
    position.set_ylabel("position from\nthe first pose (mm)")
    position.legend(fontsize=7, loc="best", ncol=3)
    turn.plot(times, np.degrees(turns), color="0.2", lw=1.2)
    turn.set_ylabel("turn from the\nfirst pose (deg)")
    trust.step(times, touching, where="mid", color="tab:purple", lw=1.2)
    trust.set_ylabel("sensors touching")
    trust.set_ylim(-0.2, max(3, int(np.max(touching, initial=0))) + 0.4)
    trust.set_xlabel("time (s)")
    if np.isfinite(confidence).any():
        share = trust.twinx()
        share.plot(times, confidence, color="tab:orange", lw=1.2)
        share.set_ylim(0, 1.05)
        share.set_ylabel("confidence", color="tab:orange")
    step = float(np.median(np.diff(times))) if len(times) > 1 else 1.0
    for ax in axes:
        for start, stop in true_runs(np.asarray(ambiguous, dtype=bool)):
            ax.axvspan(times[start] - step / 2, times[stop - 1] + step / 2, color="0.88", lw=0)
        for mode, colour in (("redetect", "tab:red"), ("hold", "0.5")):
            ax.plot(times[modes == mode], np.full(np.count_nonzero(modes == mode), 0.95), "v", ms=4, color=colour,
                    transform=ax.get_xaxis_transform())
        ax.grid(alpha=0.3)
    redetections, held = np.count_nonzero(modes == "redetect"), np.count_nonzero(modes == "hold")
    fig.suptitle(f"{title}: {len(times)} frames, {redetections} re-detections (red), {held} held (grey), "
                 f"{int(np.count_nonzero(ambiguous))} ambiguous (shaded)", fontsize=9)
    fig.tight_layout()
    return fig
