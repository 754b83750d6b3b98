"""``tactile6d bench render``: images per second of the DIGIT simulator on a database-like workload.

Samples ``-n`` surface points of a YCB mesh, places a DIGIT on each as the database does
(``sensor.sensor_poses_touching`` with the config's press depth and roll rule), renders them once to
warm up (worker start-up, caches), then times ``DigitRenderer.render_many`` on them. It also times the
two steps of one image in this process: ``contact`` (cropping, ray casting, shading) and ``compose``
(upsampling, blur, background, noise). The last line printed is one JSON object.

Wall-clock timings depend on what else runs on the machine: the JSON reports the 1-minute load average
next to them, and the CPU time per image, which does not.

    tactile6d bench render [-n N] [--object NAME] [--seed S] [key=value ...]

``key=value`` are config overrides (Hydra syntax), e.g. ``render.workers=1`` or ``render.render_step=1``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
import trimesh
from tqdm import tqdm

from tactile6d.cli import description
from tactile6d.core import sensor
from tactile6d.core.config import compose_config, section_to_dict
from tactile6d.core.geometry import invert_pose
from tactile6d.data.third_party import DataStore
from tactile6d.sim import meshes
from tactile6d.sim.database import sensor_rolls
from tactile6d.sim.render import DigitRenderer, load_background_bgr, mesh_arrays


def database_poses(mesh: trimesh.Trimesh, n: int, press_depth: float, roll: str, seed: int) -> np.ndarray:
    """(n, 4, 4) T_object_sensor: DIGITs touching n random surface points (area-uniform) of the mesh."""
    rng = np.random.default_rng(seed)
    points, faces = trimesh.sample.sample_surface(mesh, n, seed=rng)
    return sensor.sensor_poses_touching(points, mesh.face_normals[faces], sensor_rolls(roll, n, rng), press_depth)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d bench render", description=description(__doc__))
    parser.add_argument("--object", default="002_master_chef_can", help="YCB object (data directory ycb/<name>)")
    parser.add_argument("-n", type=int, default=200, help="images to time")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("overrides", nargs="*", help="config overrides key=value, e.g. render.workers=1")
    args = parser.parse_args(argv)

    cfg = compose_config(args.overrides)
    config = section_to_dict(cfg, "render")
    store = DataStore(cfg.paths)
    workers = int(config["workers"])
    mesh, _ = meshes.clean_mesh(meshes.load_mesh_file(store.path(f"ycb/{args.object}/textured_simple.obj")))
    arrays = mesh_arrays(mesh)
    poses = database_poses(mesh, args.n, config["press_depth"], config["roll"], args.seed)
    # Database sampling puts some sensors across sharp edges, where the body meets the object; the
    # database renders those as TACTO does, so the benchmark does too.
    with DigitRenderer.from_config(config, load_background_bgr(cfg, store), strict=False) as renderer:
        renderer.render_many(arrays, poses, seeds=args.seed)  # warm-up: workers start, imports, caches

        with tqdm(total=args.n, desc="bench render", unit="image") as bar:
            start = time.perf_counter()
            _, masks = renderer.render_many(arrays, poses, seeds=args.seed, progress=bar.update)
            elapsed = time.perf_counter() - start

        contact_s, compose_s = [], []
        cpu_start = time.process_time()
        for k, T in enumerate(poses):
            t0 = time.perf_counter()
            diff, depth = renderer.contact(arrays, invert_pose(T))
            t1 = time.perf_counter()
            renderer.compose(diff, depth, seed=k)
            contact_s.append(t1 - t0)
            compose_s.append(time.perf_counter() - t1)
        cpu_ms = 1000 * (time.process_time() - cpu_start) / args.n

    summary = {
        "images_per_s": round(args.n / elapsed, 1),
        "n": args.n,
        "workers": workers,
        "object": args.object,
        "render_step": config["render_step"],
        "size": [config["width"], config["height"]],
        "contact_share": round(float(masks.mean()), 3),
        "single_process_ms": {
            "contact": round(1000 * float(np.mean(contact_s)), 2),
            "compose": round(1000 * float(np.mean(compose_s)), 2),
            "total": round(1000 * float(np.mean(contact_s) + np.mean(compose_s)), 2),
        },
        # CPU time per image in one process, and what `workers` processes would give with a core each:
        # a throughput estimate that does not depend on other programs' load.
        "single_process_cpu_ms": round(cpu_ms, 2),
        "cpu_bound_images_per_s": round(workers * 1000 / cpu_ms, 1),
        "cpus": os.cpu_count(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(summary))
    return 0
