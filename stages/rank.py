"""Stage rank: the top-k distinct poses of every scene by loss + deepest sensor penetration (the paper's collision-aware ranking).

Reads ``artifacts/runs/<set>/<method>/hypotheses.h5`` (with the sensors' contacts), each scene object's
``objects/<obj>.h5`` (collision pieces and, for the re-scoring, the mesh), and config sections ``rank`` and ``sensors``. Writes ``ranked.h5`` beside it: per scene the top-k poses (S, K, 4, 4)
with their scores, losses and penetrations (rows past ``n_poses`` are NaN), and the seconds of every step
(encode, select, optimize, rank), so that the evaluation reads one file.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tqdm import tqdm

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import exit_on_error
from tactile6d.core.settings import METHODS, RankSettings, SensorSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.object_artifacts import load_collision_vertices, load_mesh
from tactile6d.data.schemas import CONTACT_FIELDS
from tactile6d.estimation.collision import PenetrationModel, vertices_to_pieces
from tactile6d.estimation.rank import rank
from tactile6d.estimation.run_storage import carried, expand_hypotheses, scene_contacts
from tactile6d.runtime.stage_args import median_or_nan, parse_run_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim.surface_sampling import sample_surface


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_run_stage_args(argv, __doc__.splitlines()[0], METHODS)
    settings = RankSettings.from_cfg(cfg.rank)
    sensors = SensorSettings.from_cfg(cfg.sensors)
    artifacts = cfg.paths.artifacts_dir
    run = layout.run_dir(artifacts, args.scene_set, args.method)
    hyp = read_artifact(run / "hypotheses.h5", "hypotheses")
    names, objects, T_world_sensors = hyp["names"], hyp["objects"], hyp["T_world_sensors"]
    models = {name: PenetrationModel(vertices_to_pieces(load_collision_vertices(artifacts, name)))
              for name in sorted(set(objects))}
    meshes = {name: load_mesh(artifacts, name) if settings.rescores else None for name in sorted(set(objects))}
    surfaces = {name: sample_surface(mesh) if settings.refine else None for name, mesh in meshes.items()}

    n_scenes, n_sensors, k = len(names), T_world_sensors.shape[1], int(settings.top_k)
    poses = np.full((n_scenes, k, 4, 4), np.nan)
    scores, losses = np.full((n_scenes, k), np.nan), np.full((n_scenes, k), np.nan)
    penetrations = np.full((n_scenes, k, n_sensors), np.nan)
    n_poses = np.zeros(n_scenes, dtype=np.int64)
    seconds = np.zeros(n_scenes)
    for s in tqdm(range(n_scenes), desc=f"rank {args.scene_set}/{args.method}", unit="scene"):
        rows = slice(hyp["offsets"][s], hyp["offsets"][s + 1])
        if rows.start == rows.stop:  # a scene whose selection failed
            continue
        candidates, losses_in = expand_hypotheses(hyp["translations"][rows], hyp["rotvecs"][rows], hyp["losses"][rows])
        t0 = time.perf_counter()
        ranked = rank(models[objects[s]], T_world_sensors[s], candidates, losses_in, settings, surfaces[objects[s]],
                      scene_contacts(hyp, s), meshes[objects[s]], sensors=sensors)
        seconds[s] = time.perf_counter() - t0
        n = n_poses[s] = len(ranked.poses)
        poses[s, :n], scores[s, :n], losses[s, :n], penetrations[s, :n] = (
            ranked.poses, ranked.scores, ranked.losses, ranked.penetrations)

    print(f"{args.scene_set}/{args.method}: {int((n_poses > 0).sum())} of {n_scenes} scenes ranked, "
          f"median {median_or_nan(seconds):.3f} s per scene")
    write_artifact(
        run / "ranked.h5",
        "ranked",
        {
            **carried(hyp, ("names", "objects", "T_world_sensors", "failure", "seconds_encode", "seconds_select",
                             "seconds_optimize") + CONTACT_FIELDS),
            "poses": poses, "scores": scores, "losses": losses, "penetrations": penetrations,
            "n_poses": n_poses, "seconds_rank": seconds,
        },
        attrs={"scene_set": args.scene_set, "method": args.method},
        config={"rank": section_to_dict(cfg, "rank"), "sensors": section_to_dict(cfg, "sensors")},
    )
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
