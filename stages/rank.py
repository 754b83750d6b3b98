"""Stage rank: the top-k distinct poses of every scene by loss + deepest sensor penetration (the paper's collision-aware ranking).

Reads ``artifacts/runs/<set>/<method>/hypotheses.h5`` (with the sensors' contacts), each scene object's
``objects/<obj>.h5`` (collision pieces and, for the re-scoring, the mesh), and config sections ``rank`` and ``sensors``. Writes ``ranked.h5`` beside it: per scene the top-k poses (S, K, 4, 4)
with their scores, losses and penetrations (rows past ``n_poses`` are NaN), and the seconds of every step
(encode, select, optimize, rank), so that the evaluation reads one file.

One executor task per scene (``tactile6d.runtime.executor``): ``executor.workers`` local processes by
default, a Dask cluster's workers when ``executor.address`` names one. A task gets its scene's hypotheses
and contacts and reads the object's artifacts by path, once per worker process; the rows come back in
scene order, so every output but the seconds is the same wherever the tasks ran.
"""

from __future__ import annotations

import sys
import time
import uuid

import numpy as np

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.core.settings import METHODS, RankSettings, SensorSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.object_artifacts import load_collision_vertices, load_mesh
from tactile6d.data.schemas import CONTACT_FIELDS
from tactile6d.estimation.collision import PenetrationModel, vertices_to_pieces
from tactile6d.estimation.rank import rank
from tactile6d.estimation.run_storage import carried, expand_hypotheses, scene_contacts
from tactile6d.perception.contacts import Contacts
from tactile6d.runtime.executor import executor_from_config, process_cache
from tactile6d.runtime.stage_args import median_or_nan, parse_run_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim.surface_sampling import sample_surface


def object_models(run: str, artifacts: str, name: str, settings: RankSettings):
    """The object's PenetrationModel, mesh (when the ranking re-scores) and surface samples (when it refines),
    loaded once per process and stage run (``process_cache``)."""
    def load():
        mesh = load_mesh(artifacts, name) if settings.rescores else None
        return (PenetrationModel(vertices_to_pieces(load_collision_vertices(artifacts, name))), mesh,
                sample_surface(mesh) if settings.refine else None)

    return process_cache(("rank object", run, str(artifacts), name, settings), load)


def rank_scene_task(run: str, artifacts: str, name: str, settings: RankSettings, sensors: SensorSettings,
                    T_world_sensors: np.ndarray, hypotheses: tuple, contacts: Contacts):
    """One task: a scene's hypotheses (translations, rotvecs, losses as hypotheses.h5 stores them) ranked for
    object ``name`` -> (``RankedPoses``, seconds of the ranking)."""
    model, mesh, surface = object_models(run, artifacts, name, settings)
    candidates, losses_in = expand_hypotheses(*hypotheses)
    t0 = time.perf_counter()
    ranked = rank(model, T_world_sensors, candidates, losses_in, settings, surface, contacts, mesh, sensors=sensors)
    return ranked, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_run_stage_args(argv, __doc__.splitlines()[0], METHODS)
    settings = RankSettings.from_cfg(cfg.rank)
    sensors = SensorSettings.from_cfg(cfg.sensors)
    artifacts = str(cfg.paths.artifacts_dir)
    workers = int(cfg.executor.workers)
    if workers < 1:
        raise ConfigError(f"executor.workers must be >= 1, got {workers}")
    run = layout.run_dir(artifacts, args.scene_set, args.method)
    hyp = read_artifact(run / "hypotheses.h5", "hypotheses")
    names, objects, T_world_sensors = hyp["names"], hyp["objects"], hyp["T_world_sensors"]

    n_scenes, n_sensors, k = len(names), T_world_sensors.shape[1], int(settings.top_k)
    poses = np.full((n_scenes, k, 4, 4), np.nan)
    scores, losses = np.full((n_scenes, k), np.nan), np.full((n_scenes, k), np.nan)
    penetrations = np.full((n_scenes, k, n_sensors), np.nan)
    n_poses = np.zeros(n_scenes, dtype=np.int64)
    seconds = np.zeros(n_scenes)
    # A scene whose selection failed has no hypotheses: nothing to rank.
    scenes = [s for s in range(n_scenes) if hyp["offsets"][s] < hyp["offsets"][s + 1]]
    rows = [slice(hyp["offsets"][s], hyp["offsets"][s + 1]) for s in scenes]
    token = uuid.uuid4().hex
    with executor_from_config(cfg, max(1, min(workers, len(scenes)))) as executor:
        results = executor.map(
            rank_scene_task, [token] * len(scenes), [artifacts] * len(scenes), [str(objects[s]) for s in scenes],
            [settings] * len(scenes), [sensors] * len(scenes), [T_world_sensors[s] for s in scenes],
            [(hyp["translations"][r], hyp["rotvecs"][r], hyp["losses"][r]) for r in rows],
            [scene_contacts(hyp, s) for s in scenes], desc=f"rank {args.scene_set}/{args.method}")
    for s, (ranked, elapsed) in zip(scenes, results):
        seconds[s] = elapsed
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
