"""Stage evaluate_own: your own objects' path measured end to end, on the scene set ``own`` (meshes an installed
package ships, config section ``own_set``: objects tactile6d was neither built nor tuned on).

Each scene is estimated, told its object, by that object's estimator as ``tactile6d estimate --object <name>``
loads it (artifacts under ``artifacts/own/``, the default settings) and its ranked poses are scored as
evaluate scores them (``scoring.scene_errors``; Table I's average over the objects, and the median over the
scenes). Then each scene is identified without being told its object, against the whole library:
``objects.names``, ``identify.distractors`` and the own objects of ``own_set.files``
(``identification_accuracy.identify_scene_set``, with the weights of stage calibrate_identify, which never
saw an own object). Writes ``artifacts/metrics/own.json``: ``meshes`` (each object's import report),
``estimate`` (``average``, per object, seconds) and ``identify``.
"""

from __future__ import annotations

import sys

import numpy as np
from tqdm import tqdm

from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json
from tactile6d.estimation.estimator import Estimator
from tactile6d.estimation.identifier import Identifier
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.evaluation.identification_accuracy import identify_scene_set
from tactile6d.evaluation.metric_table import ERROR_KEYS
from tactile6d.evaluation.sensor_subsets import estimate_and_score, scene_task_input
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim.mesh_import import own_objects


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = cfg.paths.artifacts_dir
    objects_dir = layout.own_dir(artifacts)
    names = [str(n) for n in cfg.own_set.files]
    undeclared = sorted(set(names) - set(own_objects(cfg)))
    if undeclared:
        raise ConfigError(f"own_set.files names {', '.join(undeclared)}, which config section own does not declare "
                          "(conf/own/default.yaml)")
    scenes = read_artifact(layout.scenes_file(artifacts, "own"), "scenes")
    objects = [str(o) for o in scenes["objects"]]
    references = {o: scoring.load_object_reference(objects_dir, o) for o in dict.fromkeys(objects)}
    estimators = {o: Estimator.from_artifacts(o, artifacts, cfg, objects_dir=objects_dir) for o in references}
    scored = []
    for s in tqdm(range(len(objects)), desc="estimate own", unit="scene"):
        scene = scene_task_input(scenes, s)
        scored.append(estimate_and_score(estimators[objects[s]], scene["T_world_sensors"], scene["images"],
                                         scene["T_world_object"], references[objects[s]], scene["backgrounds"]))
    errors = {key: np.stack([row.errors[key] for row in scored]) for key in ERROR_KEYS}
    estimate = scoring.summarise_by_object(errors, np.array(objects))
    seconds = [row.seconds["total"] for row in scored if row.seconds is not None]
    estimate["time_s_median"] = float(np.median(seconds)) if seconds else float("nan")
    estimate["n_failed"] = len(scored) - len(seconds)

    with Identifier.from_artifacts(list(cfg.objects.names), artifacts, cfg, distractors=list(cfg.identify.distractors),
                                   own=names) as identifier:
        print(f"identify own: {len(objects)} scenes against {len(identifier.names)} objects, screened on "
              f"{identifier.describe()}", flush=True)
        identified = identify_scene_set(identifier, scenes, references, desc="identify own")
    meshes = {o: read_artifact(layout.object_file(objects_dir, o), "object").attrs.get("import_report", {})
              for o in references}  # what prepare_own read: file, faces, extents, repairs
    write_json(layout.metrics_file(artifacts, "own"), {"n_scenes": len(objects), "meshes": meshes,
                                                       "estimate": estimate, "identify": identified})
    average = estimate.get("average", {})
    print(f"own: positional error #1 {average.get('pos_err_cm_top1', float('nan')):.2f} cm (median "
          f"{average.get('pos_err_cm_top1_median', float('nan')):.2f}), ADI-AUC #1 "
          f"{average.get('adi_auc_paper_top1', float('nan')):.1f} %; identified top-1 {100 * identified['top1']:.0f} % "
          f"among {len(identified['objects'])} objects")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
