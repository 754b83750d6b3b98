"""Stage identify: which object, on a scene set, against the whole library (``objects.names`` and ``identify.distractors``).

Each scene of the set is identified (``tactile6d.estimation.identifier``, the weights of stage calibrate_identify)
without being told its object. Writes ``artifacts/metrics/identify_<set>.json``
(``identification_accuracy.identify_scene_set``): top-1 and top-3 object accuracy, top-1 per object, the confusion
matrix (row = true object, column = the object identified first), the median and 90th-percentile
seconds per identification, and the pose metrics of the scenes identified correctly.
"""

from __future__ import annotations

import sys

from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json
from tactile6d.estimation.identifier import Identifier
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.evaluation.identification_accuracy import identify_scene_set
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = cfg.paths.artifacts_dir
    objects = [str(o) for o in cfg.objects.names]
    scenes = read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes")
    references = {o: scoring.load_object_reference(artifacts, o) for o in objects}
    with Identifier.from_artifacts(objects, artifacts, cfg, distractors=list(cfg.identify.distractors)) as identifier:
        print(f"identify {args.scene_set}: {len(scenes['names'])} scenes against {len(identifier.names)} objects, "
              f"screened on {identifier.describe()}", flush=True)
        out = {"scene_set": args.scene_set,
               **identify_scene_set(identifier, scenes, references, desc=f"identify {args.scene_set}")}
    write_json(layout.metrics_file(artifacts, f"identify_{args.scene_set}"), out)
    print(f"{args.scene_set}: top-1 {100 * out['top1']:.1f} %, top-3 {100 * out['top3']:.1f} %, "
          f"median {out['time_s_median']:.2f} s per identification")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
