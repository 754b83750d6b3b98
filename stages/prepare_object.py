"""Stage prepare_object: clean an object's mesh, build its collision geometry and metric points.

Reads: the object's mesh (data directory, or a built-in primitive), config sections ``prepare`` and
``paths``. Writes ``artifacts/objects/<name>.h5`` and ``artifacts/metrics/collision/<name>.json`` (how
well the collision pieces cover the object); with ``--distractor`` (a distractor of the identification
library) both under ``artifacts/distractors/`` instead, and with ``--distractors`` so for every distractor, spread over
``prepare.workers`` local processes (a Dask cluster's workers when ``executor.address`` names one).
"""

from __future__ import annotations

import sys

import numpy as np

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import write_artifact, write_json
from tactile6d.data.third_party import DataStore, group_files, group_names
from tactile6d.runtime.executor import map_objects
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim import meshes
from tactile6d.sim.surface_sampling import sample_surface_even


def ycb_object_names() -> list[str]:
    """The objects the data manifest has meshes for."""
    return [g.split(":", 1)[1] for g in group_names() if g.startswith("object:")]


def load_source(name: str, store: DataStore, scale: float, n_metric_points: int, rng: np.random.Generator):
    """The raw mesh and the metric points of an object -> (mesh, metric_points (K, 3), source description).

    A YCB mesh is described by its path relative to the data directory, never by where that directory
    lies on this machine: the object file must have the same bytes wherever the data is (dvc.lock's md5)."""
    if meshes.is_primitive(name):
        mesh = meshes.make_primitive(name)
        mesh.apply_scale(scale)
        points, _, _ = sample_surface_even(mesh, n_metric_points, rng)
        return mesh, points, "built-in primitive"
    if name not in ycb_object_names():
        known = ", ".join(list(ycb_object_names()) + list(meshes.PRIMITIVE_NAMES))
        raise ConfigError(f"unknown object {name!r}; known objects: {known}")
    mesh_rel = f"ycb/{name}/textured_simple.obj"
    mesh = meshes.load_mesh_file(store.path(mesh_rel), scale=scale)
    points = np.loadtxt(store.path(f"ycb/{name}/points.xyz"), dtype=np.float64).reshape(-1, 3) * scale
    return mesh, points, f"data directory: {mesh_rel}"


def collision_pieces(name: str, mesh, cfg, store: DataStore) -> meshes.ConvexPieces:
    method = cfg.prepare.collision
    if method == "coacd":
        return meshes.convex_pieces_coacd(mesh, cfg.prepare.coacd_threshold, cfg.prepare.coacd_max_pieces,
                                          cfg.prepare.seed)
    if method == "hull":
        return [(np.asarray(mesh.convex_hull.vertices), np.asarray(mesh.convex_hull.faces))]
    if method == "caddeo2023":
        if meshes.is_primitive(name):
            raise ConfigError(f"prepare.collision=caddeo2023 has no pieces for the primitive {name!r}")
        relpaths = [r for r in group_files(f"object:{name}") if "/collision_caddeo2023/" in r]
        pieces = meshes.convex_pieces_from_files([store.path(r) for r in relpaths])
        return [(v * cfg.prepare.scale, f) for v, f in pieces]
    raise ConfigError(f"prepare.collision must be coacd, hull or caddeo2023, not {method!r}")


def prepare_object(name: str, cfg, artifacts) -> str:
    """Write the object's ``objects/<name>.h5`` and collision metrics under ``artifacts``; one executor task.
    Returns the line that describes it."""
    store = DataStore(cfg.paths)
    rng = np.random.default_rng(cfg.prepare.seed)

    raw, metric_points, source = load_source(name, store, cfg.prepare.scale, cfg.prepare.n_metric_points, rng)
    meshes.check_units(raw, name)
    mesh, report = meshes.clean_mesh(raw)
    pieces = collision_pieces(name, mesh, cfg, store)
    fidelity = meshes.collision_fidelity(mesh, pieces, n=200_000, rng=rng)
    write_artifact(
        layout.object_file(artifacts, name),
        "object",
        {
            "vertices": np.asarray(mesh.vertices),
            "faces": np.asarray(mesh.faces),
            "metric_points": metric_points,
            **meshes.pack_pieces(pieces),
        },
        attrs={"object": name, "source": source, "clean_report": report, "collision_fidelity": fidelity},
        config={"prepare": section_to_dict(cfg, "prepare")},
    )
    write_json(layout.collision_metrics_file(artifacts, name), {"collision": cfg.prepare.collision, **fidelity})
    return (f"{name}: {report['faces']} faces (watertight: {report['watertight']}), "
            f"{fidelity['n_pieces']} collision pieces ({cfg.prepare.collision}): "
            f"excess {fidelity['excess']:.3f}, missing {fidelity['missing']:.3f} of the volume")


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0], per_object=True)
    # Each object is one task: coacd and the fidelity sampling run on one core.
    for line in map_objects(prepare_object, args.names, cfg, args.objects_dir, int(cfg.prepare.workers),
                            "prepare.workers", "prepare_object"):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
