"""Stage render_database: the tactile image of a DIGIT touching each surface point of an object.

Reads ``artifacts/surfaces/<name>.h5`` (M points, outward normals), ``artifacts/objects/<name>.h5`` (the
cleaned mesh), the no-contact background named by ``render.background`` (data directory) and config
section ``render``. Writes ``artifacts/databases/<name>.h5`` (schema ``database``, tactile6d.sim.database):
per point the sensor pose ``T_object_sensor`` (``sensor_poses_touching`` with ``render.press_depth`` and
the roll rule ``render.roll``), its image and contact mask stored compactly, and whether the object
enters the sensor body there (``body_contact``; rendered anyway, as TACTO would: ``render.strict`` is
not applied here); also the no-contact image. Randomness (rolls, noise) comes from the object's name
(``database.object_rng``). With ``--distractors`` it renders every distractor of the identification
library (under ``artifacts/distractors/``), one object after the other through one executor.

The poses are rendered in chunks of ``CHUNK``, one executor task each (``tactile6d.runtime.executor``, config
section ``executor``): ``render.workers`` local processes by default, a Dask cluster's workers when
``executor.address`` names one. A task gets everything it renders from (mesh arrays, poses, renderer
settings, background) and sends back the encoded images, so workers need no shared filesystem; the
chunks are appended in order, so the artifact is the same byte for byte wherever they ran.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import trimesh

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.third_party import DataStore
from tactile6d.runtime.executor import executor_from_config
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim import database
from tactile6d.sim.render import DigitRenderer, MeshArrays, add_noise, load_background_bgr, mesh_arrays, task_renderer

# Poses per task: ~0.5 s of rendering and encoding each, so 2000 points make 63 tasks, enough to keep
# a few dozen workers busy and to even out the load; the per-task cost (shipping the mesh and the
# background, ~1 MB for a YCB object) stays small beside it.
CHUNK = 32


def render_chunk(settings: dict, background_bgr: np.ndarray, mesh: MeshArrays,
                 T_object_sensors: np.ndarray) -> database.EncodedImages:
    """One task: the encoded images of sensors at T_object_sensors (k, 4, 4) on ``mesh``.

    settings: ``DigitRenderer.settings`` of a noise-free renderer; background_bgr (H, W, 3) uint8 as read.
    The renderer is built once per process (``render.task_renderer``).
    """
    renderer = task_renderer(settings, background_bgr)
    return database.render_encoded(renderer, mesh, T_object_sensors)


def render_object(name: str, cfg, artifacts, renderer: DigitRenderer, background: np.ndarray,
                  executor) -> None:
    """Write ``artifacts/databases/<name>.h5`` under ``artifacts`` from the object's mesh and surface there.

    renderer: gives the settings the tasks rebuild it from and the background they encode over;
    background: the no-contact image (H, W, 3) uint8 BGR as read; executor: where the chunks render.
    """
    start = time.perf_counter()
    surface = read_artifact(layout.surface_file(artifacts, name), "surface")
    obj = read_artifact(layout.object_file(artifacts, name), "object")
    mesh = trimesh.Trimesh(obj["vertices"], obj["faces"], process=False)
    points, normals = surface["points"], surface["normals"]
    n = len(points)
    rng = database.object_rng(name)
    rolls = database.sensor_rolls(cfg.render.roll, n, rng)
    depths = np.full(n, float(cfg.render.press_depth))
    noise_seeds = rng.integers(0, 2**62, size=n + 1)  # one per image, the last for the no-contact image
    poses = sensor_poses_touching(points, normals, rolls, depths)
    arrays = mesh_arrays(mesh)
    chunks = [poses[a : a + CHUNK] for a in range(0, n, CHUNK)]
    images = database.CompactImages(renderer.background)
    print(f"{name}: {n} images in {len(chunks)} tasks on {executor.describe()}", flush=True)
    k = len(chunks)
    for part in executor.map(render_chunk, [renderer.settings] * k, [background] * k, [arrays] * k, chunks,
                             desc=f"render_database {name}"):
        images.extend(part)
    body = database.body_contacts(mesh.vertices, poses)
    no_contact = add_noise(images.background, float(cfg.render.noise_std), int(noise_seeds[-1]))
    path = write_artifact(
        layout.database_file(artifacts, name),
        "database",
        {
            "points": points,
            "normals": normals,
            "T_object_sensor": poses,
            "rolls": rolls,
            "depths": depths,
            "no_contact": no_contact,
            "body_contact": body,
            **images.datasets(float(cfg.render.noise_std), noise_seeds[:-1]),
        },
        attrs={"object": name},
        config={"render": section_to_dict(cfg, "render")},
    )
    pixels = np.asarray(images.mask_pixels)
    print(
        f"{name}: {n} images in {time.perf_counter() - start:.1f} s, {path.stat().st_size / 2**20:.1f} MB "
        f"({path.stat().st_size / max(n, 1) / 1024:.1f} KB per image); contact in {np.count_nonzero(pixels)} "
        f"(median {np.median(pixels):.0f} pixels); object inside the sensor body at {int(body.sum())} points"
    )


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0], per_object=True)
    workers = int(cfg.render.workers)
    if workers < 1:
        raise ConfigError(f"render.workers must be >= 1, got {workers}")
    background = load_background_bgr(cfg, DataStore(cfg.paths))
    # This one only gives the settings the tasks rebuild it from and the background they encode over.
    renderer = DigitRenderer.from_config(cfg.render, background, noise_std=0.0, strict=False, workers=1)
    with executor_from_config(cfg, workers) as executor:
        for name in args.names:
            render_object(name, cfg, args.objects_dir, renderer, background, executor)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
