"""``tactile6d estimate``: an object's pose from a scene folder in the paper's triplet layout.

The folder holds ``poses_sensors.txt`` (one ``x y z ax ay az angle`` line per sensor, world frame) and
``Image_heatmap_<i>.png`` (sensor i's tactile image). The object's artifacts are read from
``--artifacts`` (default: the config's ``paths.artifacts_dir``), without DVC.

Output: the best ``T_world_object`` as one ``x y z ax ay az angle`` line, then a short summary
(scores, selection, time per step); or, with ``--json``, one JSON object with the top-K poses as 4x4
matrices, their scores, losses and penetrations, the selection diagnostics and the timings.

Config overrides (Hydra syntax) pass through, e.g. ``select.method=baseline select.delta_h=0.05
select.N=2000``, or ``preset=paper`` for the paper's method end to end.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from tactile6d.config import compose_config
from tactile6d.estimator import Estimate, Estimator
from tactile6d.geometry import pose_to_line
from tactile6d.io import read_scene_dir, read_tactile_image


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="tactile6d estimate", description=__doc__.split("\n")[0])
    parser.add_argument("--object", required=True, help="object name (its artifacts must exist)")
    parser.add_argument("--scene", required=True, help="scene folder: poses_sensors.txt + Image_heatmap_<i>.png")
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--top", type=int, default=None, help="poses to report (sets rank.top_k; default 5)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--background", default=None,
                        help="the sensor's own no-contact image (PNG, 240 x 320); default: render.background")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    return parser.parse_args(argv)


def summary(result: Estimate, cfg) -> list[str]:
    """A few human-readable lines: method, scores, selection diagnostics, time per step."""
    sel = result.selection
    lines = [
        (
            f"method {cfg.select.method}, solver {cfg.optimize.solver}: {len(result.poses)} distinct poses "
            f"of {result.n_hypotheses} hypotheses"
        ),
        (
            f"best: score {1000 * result.scores[0]:.2f} mm = loss {1000 * result.losses[0]:.2f} mm "
            f"+ deepest penetration {1000 * result.penetrations[0].max():.2f} mm"
        ),
    ]
    omegas = ", ".join(str(n) for n in sel.omega_sizes)
    if cfg.select.method == "ours":
        widened = [f"sensor {i} widened to {sel.delta_h[i]:.3g} rad" for i in np.flatnonzero(sel.widened)]
        angles = ", ".join(f"{a:.3f}" for a in result.angles)
        lines.append(f"latent angles {angles} rad; |Omega_i| {omegas} at delta_h {cfg.select.delta_h:g} rad"
                     + (f" ({'; '.join(widened)})" if widened else ""))
    else:
        lines.append(f"baseline: |Omega_i| {omegas} (every database point)")
    lines.append(f"{sel.tuples.shape[0]} tuples at delta_d {1000 * sel.delta_d:.2f} mm"
                 + (" (capped at N)" if sel.capped else ""))
    steps = ", ".join(f"{k} {v:.3f} s" for k, v in result.seconds.items())
    lines.append(f"time: {steps}")
    return lines


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    overrides = list(args.overrides) + ([f"rank.top_k={args.top}"] if args.top is not None else [])
    cfg = compose_config(overrides)
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    T_world_sensors, images = read_scene_dir(args.scene)

    t0 = time.perf_counter()
    background = read_tactile_image(args.background) if args.background else None
    estimator = Estimator.from_artifacts(args.object, artifacts, cfg, background=background)
    load_seconds = time.perf_counter() - t0
    result = estimator.estimate(T_world_sensors, images)

    if args.json:
        out = {"object": args.object, "scene": str(args.scene), "method": cfg.select.method,
               "solver": cfg.optimize.solver, "best": pose_to_line(result.best), **result.to_dict(),
               "load_seconds": load_seconds}
        print(json.dumps(out))
        return 0
    print(pose_to_line(result.best))
    for line in summary(result, cfg):
        print(line)
    print(f"(loading the artifacts took {load_seconds:.2f} s)")
    return 0
