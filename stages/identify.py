"""Stage identify: which object, on a scene set, against the whole library (``objects.names``).

Each scene of the set is identified (``tactile6d.identifier``, the weights of stage calibrate_identify)
without being told its object. Writes ``artifacts/metrics/identify_<set>.json``: top-1 and top-3
object accuracy, top-1 per object, the confusion matrix (row = true object, column = the object
identified first), the median and 90th-percentile seconds per identification, and the pose metrics
(``evaluation.summarise_by_object``, best pose) of the scenes identified correctly.
"""

from __future__ import annotations

import sys

import numpy as np
from tqdm import tqdm

from tactile6d import evaluation, identification, layout
from tactile6d.config import parse_stage_args
from tactile6d.errors import exit_on_error
from tactile6d.identifier import Identifier
from tactile6d.io import read_artifact, write_json
from tactile6d.optimize import use_cpu_devices_for

POSE_KEYS = ("pos_err_cm_top1", "adi_auc_paper_top1", "adi_auc_rot_top1")


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0],
                                 add_arguments=lambda p: p.add_argument("--scene-set", required=True))
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = cfg.paths.artifacts_dir
    objects = [str(o) for o in cfg.objects.names]
    scenes = read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes")
    identifier = Identifier.from_artifacts(objects, artifacts, cfg)
    references = {o: evaluation.load_object_reference(artifacts, o) for o in objects}
    truth, predicted, ranks, seconds, owners = [], [], [], [], []
    errors = {key: [] for key in ("position", "adi", "adi_rotation", "contact_ok")}
    try:
        for s in tqdm(range(len(scenes["names"])), desc=f"identify {args.scene_set}", unit="scene"):
            name = str(scenes["objects"][s])
            T_sensors = scenes["T_world_sensors"][s]
            result = identifier.identify(T_sensors, scenes["images"][s])
            order = [o.name for o in result.objects]
            truth.append(objects.index(name))
            predicted.append(objects.index(order[0]))
            ranks.append(order.index(name))
            seconds.append(result.seconds["total"])
            if order[0] == name:
                poses = result.best.candidate.estimate.poses
                scored = evaluation.scene_errors(poses, len(poses), scenes["T_world_object"][s], T_sensors,
                                                 references[name].points, references[name].surface,
                                                 tree=references[name].tree)
                for key in errors:
                    errors[key].append(scored[key])
                owners.append(name)
    finally:
        identifier.close()
    ranks = np.array(ranks)
    truth, predicted = np.array(truth, dtype=np.int64), np.array(predicted, dtype=np.int64)
    pose = {}
    if owners:
        average = evaluation.summarise_by_object({k: np.array(v) for k, v in errors.items()}, np.array(owners))
        pose = {k: v for k, v in average["average"].items() if k in POSE_KEYS}
    out = {
        "scene_set": args.scene_set,
        "objects": objects,
        "n_scenes": int(len(ranks)),
        "top1": float(np.mean(ranks == 0)) if len(ranks) else float("nan"),
        "top3": float(np.mean(ranks < 3)) if len(ranks) else float("nan"),
        "top1_by_object": {o: float(np.mean(predicted[truth == i] == i)) for i, o in enumerate(objects)
                           if np.any(truth == i)},
        "confusion": identification.confusion_matrix(truth, predicted, len(objects)).tolist(),
        "time_s_median": float(np.median(seconds)) if seconds else float("nan"),
        "time_s_p90": float(np.percentile(seconds, 90)) if seconds else float("nan"),
        "pose_of_correct": pose,
    }
    write_json(layout.metrics_file(artifacts, f"identify_{args.scene_set}"), out)
    print(f"{args.scene_set}: top-1 {100 * out['top1']:.1f} %, top-3 {100 * out['top3']:.1f} %, "
          f"median {out['time_s_median']:.2f} s per identification")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(main))
