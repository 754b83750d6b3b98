"""``tactile6d add-object NAME MESH --units mm``: a mesh file of yours as a library object, in one command.

In a checkout of the project (``--repo``, default the current directory):

1. reads and checks the mesh as stage ``prepare_own`` will (``tactile6d.sim.mesh_import``: units against the
   object's size, degenerate and duplicate faces, several bodies, holes, winding) and prints what it
   repaired; a mesh it refuses is one ``error:`` line, and nothing is written;
2. adds the entry ``own.<NAME>`` (mesh, units, scale, offset) to ``conf/own/default.yaml``, keeping the
   file's header comment, and refreshes ``params.yaml`` (``conf/`` composed), which plain ``dvc repro``
   reads;
3. runs ``dvc repro prepare_own@NAME sample_own@NAME render_own@NAME encode_own@NAME`` there (through
   ``scripts/dvc_fast_lock.py`` when the checkout has it), with DVC's own output and the stages' progress
   bars, and prints each stage's time from its record (``artifacts/times/stages/``). DVC re-uses the
   trained autoencoder and every other object's artifacts; in a fresh clone it first makes what the four
   stages need (the autoencoder's training set and training, some 9 minutes on the 2-core machine).

The mesh path is stored relative to the checkout when the file is inside it, absolute otherwise.
``--no-run`` stops after step 2; ``--replace`` overwrites an entry of the same name. Exit status: 0, 2 for
an error (a bad mesh, a name taken, no checkout), DVC's own when a stage fails. docs/own_objects.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import yaml

from tactile6d.cli import description
from tactile6d.core.config import composed_params_yaml
from tactile6d.core.errors import ConfigError, InputError
from tactile6d.data.object_artifacts import OWN_STAGES
from tactile6d.runtime.stage_clock import STAGES_DIR
from tactile6d.sim.mesh_import import UNITS, MeshSource

OWN_FILE = Path("conf") / "own" / "default.yaml"


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="tactile6d add-object", description=description(__doc__),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", help="the object's name (letters, digits, _ . -), as estimate and identify take it")
    parser.add_argument("mesh", help="the mesh file: OBJ, STL, PLY or GLB")
    parser.add_argument("--units", required=True, choices=list(UNITS), help="the file's length unit")
    parser.add_argument("--scale", type=float, default=1.0, help="a factor on top of the units (default 1)")
    parser.add_argument("--offset", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"),
                        help="metres added to every vertex after scaling: moves the object's frame")
    parser.add_argument("--repo", default=".", help="the project checkout (default: the current directory)")
    parser.add_argument("--replace", action="store_true", help="overwrite an entry of the same name")
    parser.add_argument("--no-run", action="store_true", help="write the entry and params.yaml, run no stage")
    return parser.parse_args(argv)


def dvc_targets(name: str) -> list[str]:
    """The ``dvc repro`` targets that make an own object's artifacts, in pipeline order."""
    return [f"{stage}@{name}" for stage in OWN_STAGES.values()]  # in pipeline order


def stored_mesh_path(mesh: Path, repo: Path) -> str:
    """The mesh path as the entry stores it: relative to the checkout when the file is inside it (the
    stages run there), absolute otherwise."""
    mesh, repo = mesh.resolve(), repo.resolve()
    return str(mesh.relative_to(repo)) if mesh.is_relative_to(repo) else str(mesh)


def add_entry(own_file: Path, source: MeshSource, mesh_text: str, replace: bool = False) -> None:
    """Add ``source`` as ``own.<name>`` to the config file ``own_file`` (a mapping of entries under a header
    comment, which is kept); InputError when the name is there and ``replace`` is off."""
    text = own_file.read_text() if own_file.is_file() else ""
    lines = text.splitlines(keepends=True)
    header = "".join(line for line in lines[: next((i for i, line in enumerate(lines) if not line.startswith("#")),
                                                   len(lines))])
    entries = yaml.safe_load(text[len(header):]) or {}
    if not isinstance(entries, dict):
        raise ConfigError(f"{own_file}: expected a mapping of own objects, got {type(entries).__name__}")
    if source.name in entries and not replace:
        raise InputError(f"{source.name!r} is already in {own_file} (mesh {entries[source.name].get('mesh')}); "
                         "pass --replace to overwrite it, or choose another name")
    entries[source.name] = {"mesh": mesh_text, "units": source.units, "scale": source.scale,
                            "offset": list(source.offset)}
    own_file.parent.mkdir(parents=True, exist_ok=True)
    own_file.write_text(header + yaml.safe_dump(entries, sort_keys=False, default_flow_style=None))


def dvc_command(repo: Path) -> list[str]:
    """How to start DVC in ``repo``: through its scripts/dvc_fast_lock.py when it has one (docs/pipeline.md)."""
    fast = repo / "scripts" / "dvc_fast_lock.py"
    return [sys.executable, str(fast)] if fast.is_file() else [sys.executable, "-m", "dvc"]


def stage_times(repo: Path, name: str) -> list[tuple[str, float | None]]:
    """Each of the four stages' recorded seconds (None when it has no record)."""
    out = []
    for target in dvc_targets(name):
        record = repo / STAGES_DIR / f"{target}.json"
        out.append((target, json.loads(record.read_text())["seconds"] if record.is_file() else None))
    return out


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    repo = Path(args.repo)
    if not (repo / "dvc.yaml").is_file() or not (repo / "conf" / "config.yaml").is_file():
        raise InputError(f"{repo.resolve()} is not a tactile6d checkout (no dvc.yaml and conf/config.yaml); "
                         "run add-object there or pass --repo")
    entry = {"mesh": args.mesh, "units": args.units, "scale": args.scale, "offset": list(args.offset)}
    source = MeshSource.from_config(args.name, entry)  # ConfigError for a bad name, scale or offset
    t0 = time.perf_counter()
    mesh, report = source.load()  # MeshError for a mesh the prepare stage would refuse
    print(f"{args.name}: {report.faces} faces, {' x '.join(f'{100 * e:.1f}' for e in report.extents_m)} cm"
          + "".join(f"; {r}" for r in report.repairs) + f" (checked in {time.perf_counter() - t0:.1f} s)")
    add_entry(repo / OWN_FILE, source, stored_mesh_path(Path(args.mesh), repo), args.replace)
    (repo / "params.yaml").write_text(composed_params_yaml(repo / "conf"))
    print(f"{args.name}: added to {OWN_FILE} and params.yaml")
    if args.no_run:
        print(f"make its artifacts with `dvc repro {' '.join(dvc_targets(args.name))}`")
        return 0
    start = time.perf_counter()
    env = dict(os.environ, DVC_NO_ANALYTICS=os.environ.get("DVC_NO_ANALYTICS", "1"))
    status = subprocess.run([*dvc_command(repo), "repro", *dvc_targets(args.name)], cwd=repo, env=env).returncode
    if status != 0:
        return status
    for target, seconds in stage_times(repo, args.name):  # a stage DVC skipped keeps the time of the run that made it
        print(f"  {target}: {'no record' if seconds is None else f'{seconds:.1f} s (its record)'}")
    print(f"{args.name}: ready in {time.perf_counter() - start:.0f} s; `tactile6d estimate --object {args.name} "
          f"--scene DIR`")
    return 0
