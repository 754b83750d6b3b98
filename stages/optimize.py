"""Stage optimize: pose hypotheses for every scene's tuples (the paper's optimisation step).

Reads ``artifacts/runs/<set>/<method>/tuples.h5`` (tuples and the sensors' contacts), each scene object's
``surfaces/<obj>.h5``, and config sections ``optimize`` and ``sensors``. Writes ``hypotheses.h5`` beside it: per scene the hypotheses stacked with offsets,
each stored compactly as float32 translation (m) and rotation vector (rad), its loss (m, float32) and the
index of its tuple within the scene; plus the seconds spent optimising each scene.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tqdm import tqdm

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import exit_on_error
from tactile6d.core.settings import METHODS, OptimizeSettings, SensorSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.object_artifacts import load_surface_normals, load_surface_points
from tactile6d.data.schemas import CONTACT_FIELDS, PATCH_FIELDS
from tactile6d.estimation.optimize import optimize, use_cpu_devices
from tactile6d.estimation.run_storage import carried, compact_hypotheses, scene_contacts, scene_rows, stack_ragged
from tactile6d.runtime.stage_args import median_or_nan, parse_run_stage_args
from tactile6d.runtime.stage_clock import timed


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_run_stage_args(argv, __doc__.splitlines()[0], METHODS)
    settings = OptimizeSettings.from_cfg(cfg.optimize)
    sensors = SensorSettings.from_cfg(cfg.sensors)
    if settings.solver == "gd":
        use_cpu_devices(settings.cpu_devices)  # before JAX runs anything in this process
    artifacts = cfg.paths.artifacts_dir
    run = layout.run_dir(artifacts, args.scene_set, args.method)
    selected = read_artifact(run / "tuples.h5", "tuples")
    names, objects = selected["names"], selected["objects"]
    points_of = {name: load_surface_points(artifacts, name) for name in sorted(set(objects))}
    normals_of = {name: load_surface_normals(artifacts, name) if settings.normal_weight > 0 else None
                  for name in sorted(set(objects))}

    poses, losses, tuple_index = [], [], []
    seconds = np.zeros(len(names))
    for s in tqdm(range(len(names)), desc=f"optimize {args.scene_set}/{args.method}", unit="scene"):
        tuples = scene_rows(selected["tuples"], selected["offsets"], s).astype(np.int64)
        if tuples.shape[0] == 0:  # a scene whose selection failed
            poses.append(np.zeros((0, 4, 4)))
            losses.append(np.zeros(0))
            tuple_index.append(np.zeros(0))
            continue
        t0 = time.perf_counter()
        hypotheses = optimize(points_of[objects[s]], scene_contacts(selected, s), tuples, settings,
                              normals_of[objects[s]], sensors=sensors)
        seconds[s] = time.perf_counter() - t0
        poses.append(hypotheses.poses)
        losses.append(hypotheses.losses)
        tuple_index.append(hypotheses.tuple_index)

    all_poses, offsets = stack_ragged(poses, (4, 4), np.float64)
    print(f"{args.scene_set}/{args.method}: {offsets[-1]} hypotheses over {len(names)} scenes "
          f"({settings.solver}), median {median_or_nan(seconds):.3f} s per scene")
    write_artifact(
        run / "hypotheses.h5",
        "hypotheses",
        {
            **carried(selected, ("names", "objects", "T_world_sensors", "failure", "seconds_encode", "seconds_select")
                      + CONTACT_FIELDS + PATCH_FIELDS),
            **compact_hypotheses(all_poses, stack_ragged(losses, (), np.float64)[0]),
            "tuple_index": stack_ragged(tuple_index, (), np.int32)[0],
            "offsets": offsets,
            "seconds_optimize": seconds,
        },
        attrs={"scene_set": args.scene_set, "method": args.method},
        config={"optimize": section_to_dict(cfg, "optimize"), "sensors": section_to_dict(cfg, "sensors")},
        compression="lzf",
    )
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
