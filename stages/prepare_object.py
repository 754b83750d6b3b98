"""Stage prepare_object: clean an object's mesh, build its collision geometry and metric points.

Reads: the object's mesh (data directory, a built-in primitive, or with ``--own`` your own mesh file of
config section ``own``), config sections ``prepare`` and ``paths``. Writes ``artifacts/objects/<name>.h5``
and ``artifacts/metrics/collision/<name>.json`` (how well the collision pieces cover the object); with
``--distractor`` (a distractor of the identification library) both under ``artifacts/distractors/``
instead, with ``--own`` under ``artifacts/own/``, and with ``--distractors`` so for every distractor,
spread over ``prepare.workers`` local processes (a Dask cluster's workers when ``executor.address`` names
one).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping

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
from tactile6d.sim.mesh_import import MeshSource, own_objects
from tactile6d.sim.surface_sampling import sample_surface_even


def ycb_object_names() -> list[str]:
    """The objects the data manifest has meshes for."""
    return [g.split(":", 1)[1] for g in group_names() if g.startswith("object:")]


def load_source(name: str, store: DataStore, scale: float, n_metric_points: int, rng: np.random.Generator,
                own: Mapping[str, MeshSource] | None = None):
    """The raw mesh and the metric points of an object -> (mesh, metric_points (K, 3), source description,
    the import report of your own object's mesh or None).

    A YCB mesh is described by its path relative to the data directory, never by where that directory
    lies on this machine: the object file must have the same bytes wherever the data is (dvc.lock's md5).
    Your own object (``own``: config section ``own``, ``mesh_import.own_objects``) is read in its declared
    units and scale (``prepare.scale`` is the YCB meshes' factor) and described by its path as configured;
    without metric points of its own, they are sampled evenly over its surface, as for a primitive."""
    if own and name in own:
        if meshes.is_primitive(name) or name in ycb_object_names():
            taken = "built-in shape" if meshes.is_primitive(name) else "YCB object"
            raise ConfigError(f"own.{name}: the name is taken by a {taken}; give your object another name")
        mesh, report = own[name].load()
        points, _, _ = sample_surface_even(mesh, n_metric_points, rng)
        return mesh, points, f"mesh file: {own[name].mesh} ({own[name].units})", report.to_dict()
    if meshes.is_primitive(name):
        mesh = meshes.make_primitive(name)
        mesh.apply_scale(scale)
        points, _, _ = sample_surface_even(mesh, n_metric_points, rng)
        return mesh, points, "built-in primitive", None
    if name not in ycb_object_names():
        known = ", ".join(list(ycb_object_names()) + list(meshes.PRIMITIVE_NAMES))
        raise ConfigError(f"unknown object {name!r}; known objects: {known}; your own mesh files: config section "
                          "own (docs/own_objects.md)")
    mesh_rel = f"ycb/{name}/textured_simple.obj"
    mesh = meshes.load_mesh_file(store.path(mesh_rel), scale=scale)
    points = np.loadtxt(store.path(f"ycb/{name}/points.xyz"), dtype=np.float64).reshape(-1, 3) * scale
    return mesh, points, f"data directory: {mesh_rel}", None


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

    raw, metric_points, source, imported = load_source(name, store, cfg.prepare.scale, cfg.prepare.n_metric_points,
                                                       rng, own_objects(cfg))
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
        attrs={"object": name, "source": source, "clean_report": report, "collision_fidelity": fidelity,
               **({"import_report": imported} if imported is not None else {})},
        config={"prepare": section_to_dict(cfg, "prepare")},
    )
    write_json(layout.collision_metrics_file(artifacts, name), {"collision": cfg.prepare.collision, **fidelity})
    repairs = "".join(f"; {r}" for r in (imported or {}).get("repairs", []))
    return (f"{name}: {report['faces']} faces (watertight: {report['watertight']}), "
            f"{fidelity['n_pieces']} collision pieces ({cfg.prepare.collision}): "
            f"excess {fidelity['excess']:.3f}, missing {fidelity['missing']:.3f} of the volume{repairs}")


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0], per_object=True)
    # Each object is one task: coacd and the fidelity sampling run on one core.
    for line in map_objects(prepare_object, args.names, cfg, args.objects_dir, int(cfg.prepare.workers),
                            "prepare.workers", "prepare_object"):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
