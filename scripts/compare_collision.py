"""Measure how well each collision-geometry option covers the 10 YCB objects (the table of docs/collision.md).

    python scripts/compare_collision.py [--samples 200000]

For each object: CoACD's decomposition, the paper's PhysX pieces (`collision_caddeo2023`), and one
convex hull, each scored by `meshes.collision_fidelity` (excess and missing volume, as fractions of
the object's volume) with the seconds it took to build.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from tactile6d.core.config import compose_config
from tactile6d.data.third_party import DataStore, group_files
from tactile6d.sim import meshes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000)
    args = parser.parse_args()
    cfg = compose_config()
    store = DataStore(cfg.paths)
    print(f"{'object':22s} {'method':10s} {'pieces':>6s} {'excess':>7s} {'missing':>7s} {'seconds':>7s}")
    for name in cfg.objects.names:
        mesh, _ = meshes.clean_mesh(meshes.load_mesh_file(store.path(f"ycb/{name}/textured_simple.obj")))
        builders = {
            # default arguments bind this object's mesh and name (each builder runs in this iteration anyway)
            "coacd": lambda mesh=mesh: meshes.convex_pieces_coacd(
                mesh, cfg.prepare.coacd_threshold, cfg.prepare.coacd_max_pieces, 0),
            "caddeo2023": lambda name=name: meshes.convex_pieces_from_files(
                [store.path(r) for r in group_files(f"object:{name}") if "/collision_caddeo2023/" in r]),
            "hull": lambda mesh=mesh: [(np.asarray(mesh.convex_hull.vertices), np.asarray(mesh.convex_hull.faces))],
        }
        for method, build in builders.items():
            start = time.perf_counter()
            pieces = build()
            seconds = time.perf_counter() - start
            fid = meshes.collision_fidelity(mesh, pieces, args.samples, np.random.default_rng(0))
            print(f"{name:22s} {method:10s} {fid['n_pieces']:6d} {fid['excess']:7.3f} {fid['missing']:7.3f} {seconds:7.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
