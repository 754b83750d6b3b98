"""Stage sample_surface: M points spread evenly over an object's surface, with outward normals.

Reads ``artifacts/objects/<name>.h5`` and config section ``sample``; writes
``artifacts/surfaces/<name>.h5`` (with ``--distractor``, or ``--distractors`` for the whole identification
library in one run, its objects spread over ``sample.workers`` local processes: both under
``artifacts/distractors/``).
"""

from __future__ import annotations

import sys

import numpy as np
import trimesh

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.runtime.executor import map_objects
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim.surface_sampling import nearest_neighbour_distances, sample_surface_even


def sample_object(name: str, cfg, artifacts) -> str:
    """Write ``artifacts/surfaces/<name>.h5`` under ``artifacts`` from the object's cleaned mesh there; one
    executor task. Returns the line that describes it."""
    obj = read_artifact(layout.object_file(artifacts, name), "object")
    mesh = trimesh.Trimesh(obj["vertices"], obj["faces"], process=False)
    rng = np.random.default_rng(cfg.sample.seed)
    points, normals, faces = sample_surface_even(mesh, int(cfg.sample.M), rng, int(cfg.sample.oversample))
    nn = nearest_neighbour_distances(points)
    spacing = {"nn_mean_m": float(nn.mean()), "nn_min_m": float(nn.min()), "nn_min_over_mean": float(nn.min() / nn.mean())}
    write_artifact(
        layout.surface_file(artifacts, name),
        "surface",
        {"points": points, "normals": normals, "face_index": faces},
        attrs={"object": name, "spacing": spacing},
        config={"sample": section_to_dict(cfg, "sample")},
    )
    return (f"{name}: {len(points)} points, nearest-neighbour distance mean {1000 * nn.mean():.2f} mm, "
            f"min/mean {spacing['nn_min_over_mean']:.2f}")


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0], per_object=True)
    if int(cfg.sample.M) < 1 or int(cfg.sample.oversample) < 1:
        raise ConfigError(f"sample.M and sample.oversample must be positive, got {cfg.sample.M}, {cfg.sample.oversample}")
    for line in map_objects(sample_object, args.names, cfg, args.objects_dir, int(cfg.sample.workers),
                            "sample.workers", "sample_surface"):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
