"""Could any tracker tell? Where the track is lost, do the presses fit the wrong pose as well as the truth?

    python scripts/track_ambiguity.py --artifacts artifacts [--sequences 5] [--lost-cm 2] [override ...]

Each sequence of ``artifacts/sequences/tracking.h5`` is tracked as stage evaluate_tracking tracks it (default
settings, the sensor poses as the hand reports them). On every frame whose tracked pose is over ``--lost-cm``
from the truth, three worlds are pressed into the sensors by the project's renderer (``DigitRenderer.contact``:
the noise-free press depth on its ray grid, which is what the images show):

- *recorded*: the object at the true pose, the sensors at their true poses: the presses the images show;
- *truth, as reported*: the object at the true pose, the sensors where the hand reports them: what an
  estimator that trusts the reported poses expects from the truth;
- *tracked, as reported*: the object at the tracked pose, the sensors where the hand reports them.

Printed per lost run, means over its frames and sensors: each world's mask IoU (pressed pixels) with the
recorded one, and the mean absolute press-depth difference (mm) over the pixels either presses. When the
tracked pose, through the reported sensor poses, reproduces the recorded presses as well as the truth does,
the images and the reported poses favour the wrong pose: it needs no kinematic error to explain them, the truth
needs the one the hand made. Fed the true sensor poses (``--true-sensors``), the question is whether the
images alone can tell. A diagnostic: it writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.geometry import invert_pose  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.data.object_artifacts import load_mesh  # noqa: E402
from tactile6d.data.third_party import DataStore  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.estimation.optimize import use_cpu_devices_for  # noqa: E402
from tactile6d.estimation.tracker import Tracker, TrackSettings  # noqa: E402
from tactile6d.evaluation.tracking_accuracy import track_frames, true_runs  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.render import DigitRenderer, load_background_bgr, mesh_arrays  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def press_agreement(renderer: DigitRenderer, arrays, T_object: np.ndarray, T_sensors: np.ndarray,
                    recorded: list[np.ndarray]) -> tuple[float, float]:
    """The object at T_object (4, 4) pressed into sensors T_sensors (L, 4, 4) against the recorded press
    depths (L of (h, w) m) -> (mean mask IoU, mean absolute depth difference in mm over either press)."""
    ious, diffs = [], []
    for T_s, ref in zip(T_sensors, recorded):
        _, depth = renderer.contact(arrays, invert_pose(T_s) @ T_object)
        a, b = depth > 0, ref > 0
        union = a | b
        if not union.any():
            continue  # neither presses this sensor: nothing to compare
        ious.append((a & b).sum() / union.sum())
        diffs.append(1e3 * float(np.abs(depth - ref)[union].mean()))
    return float(np.mean(ious)), float(np.mean(diffs))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--sequences", type=int, nargs="*", default=None, help="sequence indices (default: all)")
    parser.add_argument("--lost-cm", type=float, default=2.0)
    parser.add_argument("--true-sensors", action="store_true", help="track through the true sensor poses")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    seq = read_artifact(layout.sequences_file(args.artifacts, "tracking"), "sequences")
    renderer = DigitRenderer.from_config(cfg.render, load_background_bgr(cfg, DataStore(cfg.paths)), workers=1)
    renderer.strict = False  # a wrong pose may reach into a sensor's body: still a press to compare
    fps = float(np.asarray(seq["fps"]).reshape(-1)[0])
    settings = replace(TrackSettings.from_cfg(cfg.track), threads=1)
    chosen = range(len(seq["objects"])) if args.sequences is None else args.sequences
    for q in chosen:
        obj = str(seq["objects"][q])
        truth, T_true = np.asarray(seq["T_world_object"][q]), np.asarray(seq["T_world_sensors_true"][q])
        T_reported = T_true if args.true_sensors else np.asarray(seq["T_world_sensors"][q])
        with Tracker(Estimator.from_artifacts(obj, args.artifacts, cfg), settings) as tracker:
            poses = np.stack([a.pose for a in track_frames(tracker.update, T_reported, np.asarray(seq["images"][q]))])
        error = np.linalg.norm(poses[:, :3, 3] - truth[:, :3, 3], axis=1)
        lost = ~(error <= 1e-2 * args.lost_cm)
        runs = true_runs(lost)
        print(f"{seq['names'][q]} ({obj}): {int(lost.sum())} of {len(lost)} frames over {args.lost_cm:g} cm", flush=True)
        arrays = mesh_arrays(load_mesh(args.artifacts, obj))
        for start, stop in runs:
            rows = []
            for f in range(start, stop):
                if not np.isfinite(poses[f]).all():
                    continue
                recorded = [renderer.contact(arrays, invert_pose(T_s) @ truth[f])[1] for T_s in T_true[f]]
                rows.append(press_agreement(renderer, arrays, truth[f], T_reported[f], recorded)
                            + press_agreement(renderer, arrays, poses[f], T_reported[f], recorded))
            if not rows:
                continue
            r = np.mean(rows, axis=0)
            print(f"  frames {start}-{stop - 1} ({(stop - start) / fps:.2f} s, {100 * error[start:stop].mean():.1f} cm "
                  f"off): truth as reported IoU {r[0]:.2f}, depth off {r[1]:.3f} mm; tracked as reported IoU "
                  f"{r[2]:.2f}, depth off {r[3]:.3f} mm", flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
