"""Stage render_database: the tactile image of a DIGIT touching each surface point of an object.

Reads ``artifacts/surfaces/<name>.h5`` (M points, outward normals), ``artifacts/objects/<name>.h5`` (the
cleaned mesh), the no-contact background named by ``render.background`` (data directory) and config
section ``render``. Writes ``artifacts/databases/<name>.h5`` (schema ``database``, tactile6d.database):
per point the sensor pose ``T_object_sensor`` (``sensor_poses_touching`` with ``render.press_depth`` and
the roll rule ``render.roll``), its image and contact mask stored compactly, and whether the object
enters the sensor body there (``body_contact``; rendered anyway, as TACTO would: ``render.strict`` is
not applied here); also the no-contact image. Randomness (rolls, noise) comes from the object's name
(``database.object_rng``).
"""

from __future__ import annotations

import sys
import time

import numpy as np
import trimesh
from tqdm import tqdm

from tactile6d import database, layout
from tactile6d.config import parse_stage_args, section_to_dict
from tactile6d.data import DataStore
from tactile6d.errors import exit_on_error
from tactile6d.io import read_artifact, write_artifact
from tactile6d.render import DigitRenderer, add_noise, load_background_bgr, mesh_arrays
from tactile6d.sensor import sensor_poses_touching


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0], per_object=True)
    start = time.perf_counter()
    artifacts = args.objects_dir
    name = args.object
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

    background = load_background_bgr(cfg, DataStore(cfg.paths))
    with DigitRenderer.from_config(cfg.render, background, noise_std=0.0, strict=False) as renderer:
        images = database.CompactImages(renderer.background)
        with tqdm(total=n, desc=f"render_database {name}", unit="image") as bar:
            database.render_compact(renderer, mesh_arrays(mesh), poses, images, progress=bar.update)
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
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(main))
