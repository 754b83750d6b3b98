"""``tactile6d bench add-object``: the wall time of ``tactile6d add-object`` on a mesh of about 20 000 faces, run
in this checkout as a user runs it, which the bench then leaves as it found it.

The mesh: pybullet_data's duck (4212 faces, declared in cm, scale 8: 13 cm long) with its longest edges
split until it has at least ``--faces`` faces (trimesh's ``subdivide_to_size``; the same shape, more
triangles), written to a temporary OBJ; or ``--mesh FILE --units U [--scale S]``. The command runs in a
child process, DVC included (the four stages ``prepare_own``, ``sample_own``, ``render_own``,
``encode_own``; the trained autoencoder must be there: ``make reproduce`` first). Afterwards the bench
puts back ``conf/own/default.yaml``, ``params.yaml`` and ``dvc.lock`` as they were and deletes the
object's artifacts and time records, so nothing of it stays but blobs in DVC's cache. Prints each stage's
recorded seconds, then, as its last line, one JSON object with ``seconds`` (the whole command), ``faces``,
``stages`` and the 1-minute load average, since wall-clock times depend on what else runs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pybullet_data
import trimesh

from tactile6d.cli import description
from tactile6d.cli.add_object import OWN_FILE, dvc_targets, stage_times
from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.data import layout
from tactile6d.runtime.stage_clock import STAGES_DIR
from tactile6d.sim.mesh_import import own_objects
from tactile6d.sim.meshes import load_mesh_file

NAME = "bench_add_object"
DUCK = Path(pybullet_data.getDataPath()) / "duck.obj"
# Files add-object writes in the checkout, put back afterwards.
RESTORED = (OWN_FILE, Path("params.yaml"), Path("dvc.lock"))


def subdivided_mesh(path: Path, faces: int) -> trimesh.Trimesh:
    """The mesh of ``path`` with its longest edges split until it has at least ``faces`` faces (the same
    surface, more triangles): the edge length limit lowered by 10 % at a time."""
    mesh = load_mesh_file(path)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    edge = float(mesh.edges_unique_length.max())
    out = mesh
    while len(out.faces) < faces:
        edge *= 0.9
        vertices, tris = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=edge)
        out = trimesh.Trimesh(vertices, tris, process=False)
    return out


def own_artifacts(repo: Path, name: str) -> list[Path]:
    """The files the four own stages write for ``name`` in checkout ``repo``."""
    own = layout.own_dir(repo / "artifacts")
    return [layout.object_file(own, name), layout.surface_file(own, name), layout.database_file(own, name),
            layout.latents_file(own, name), layout.collision_metrics_file(own, name),
            *(repo / STAGES_DIR / f"{target}.json" for target in dvc_targets(name))]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d bench add-object", description=description(__doc__))
    parser.add_argument("--faces", type=int, default=20_000, help="subdivide the duck to at least this many faces")
    parser.add_argument("--mesh", default=None, help="time this mesh file instead (with --units, --scale)")
    parser.add_argument("--units", default="cm")
    parser.add_argument("--scale", type=float, default=8.0)
    parser.add_argument("--repo", default=".", help="the checkout (default: the current directory)")
    args = parser.parse_args(argv)
    repo = Path(args.repo).resolve()
    if not (repo / "dvc.yaml").is_file():
        raise InputError(f"{repo} is not a tactile6d checkout (no dvc.yaml); run the bench there or pass --repo")
    if not layout.ae_checkpoint(repo / "artifacts").is_file():
        raise InputError(f"{layout.ae_checkpoint(repo / 'artifacts')} is missing: add-object reuses the trained "
                         "autoencoder; run `make reproduce` (or `dvc repro train_ae`) first")
    if NAME in own_objects(compose_config(conf_dir=repo / "conf")):
        raise InputError(f"{repo / OWN_FILE} already has an entry {NAME}: remove it first")
    saved = {path: (repo / path).read_bytes() for path in RESTORED if (repo / path).is_file()}
    with tempfile.TemporaryDirectory() as tmp:
        if args.mesh is None:
            mesh_path, units, scale = Path(tmp) / "duck_subdivided.obj", "cm", 8.0
            mesh = subdivided_mesh(DUCK, args.faces)
            mesh.export(mesh_path)
        else:
            mesh_path, units, scale = Path(args.mesh).resolve(), args.units, args.scale
            mesh = load_mesh_file(mesh_path)
        faces = int(len(mesh.faces))
        print(f"tactile6d add-object {NAME} {mesh_path} --units {units} --scale {scale:g}  ({faces} faces)", flush=True)
        command = [sys.executable, "-m", "tactile6d.cli", "add-object", NAME, str(mesh_path), "--units", units,
                   "--scale", str(scale), "--repo", str(repo)]
        start = time.perf_counter()
        try:
            status = subprocess.run(command, cwd=repo).returncode
            seconds = time.perf_counter() - start
            stages = dict(stage_times(repo, NAME))
        finally:
            for path, content in saved.items():
                (repo / path).write_bytes(content)
            for path in own_artifacts(repo, NAME):
                path.unlink(missing_ok=True)
    if status != 0:
        print(f"add-object failed (exit status {status}); the checkout is restored", file=sys.stderr)
        return status
    print(f"tactile6d add-object: {seconds:.1f} s for {faces} faces "
          f"[{', '.join(f'{t} {s:.1f} s' for t, s in stages.items() if s is not None)}]")
    print(json.dumps({"seconds": seconds, "faces": faces, "stages": stages,
                      "load_average_1min": os.getloadavg()[0], "cpu_count": os.cpu_count()}))
    return 0
