"""Where a sensor touches, how deep the object's real surface lies inside its collision pieces.

    python scripts/collision_excess.py --artifacts artifacts [--objects NAME ...]

The ranking measures a pose's penetration into each DIGIT body with the object's convex pieces
(``artifacts/objects/<name>.h5``, stage ``prepare_object``). Pieces cover a concave object with some excess
volume; where that excess lies on the surface a sensor can touch, a sensor that only touches looks like it
presses in. For each object this samples its surface as the refinement does (``surface_sampling.sample_surface``,
1 mm spacing) and prints how deep each sample lies inside the pieces (its largest depth over the pieces, from
each piece's face planes): median, 90th and 99th percentiles, the largest, and the share of the surface buried
more than 1 and 2 mm (the ranking lets ``sensors.contact_sigma``, 1.65 mm by default, of penetration go free).
A diagnostic: it writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data.object_artifacts import load_collision_vertices, load_mesh  # noqa: E402
from tactile6d.estimation.collision import ConvexPieces, vertices_to_pieces  # noqa: E402
from tactile6d.sim.surface_sampling import sample_surface  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def points_to_piece_depth(points: np.ndarray, pieces: ConvexPieces) -> np.ndarray:
    """(n, 3) object-frame points -> (n,) m: how deep each lies inside the union of the pieces (the largest,
    over pieces, of its distance to the nearest face plane; 0 outside every piece)."""
    depth = np.zeros(len(points))
    for vertices, faces in zip(pieces.vertices, pieces.faces):
        a, b, c = (vertices[faces[:, k]] for k in range(3))
        normals = np.cross(b - a, c - a)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        inside = (np.sum(normals * a, axis=1)[None] - points @ normals.T).min(axis=1)
        depth = np.maximum(depth, inside)
    return depth


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--objects", nargs="*", help="object names (default: objects.names of the config)")
    args = parser.parse_args(argv)
    names = args.objects or list(compose_config().objects.names)
    print("| object | pieces | median (mm) | p90 | p99 | max | buried > 1 mm | > 2 mm |")
    print("|---|---|---|---|---|---|---|---|")
    for name in names:
        pieces = vertices_to_pieces(load_collision_vertices(args.artifacts, name))
        d = 1000 * points_to_piece_depth(sample_surface(load_mesh(args.artifacts, name)).points, pieces)
        print(f"| {name} | {len(pieces.vertices)} | {np.median(d):.2f} | {np.percentile(d, 90):.2f} | "
              f"{np.percentile(d, 99):.2f} | {d.max():.2f} | {100 * np.mean(d > 1):.1f} % | {100 * np.mean(d > 2):.1f} % |",
              flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
