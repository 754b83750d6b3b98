"""How well the identifier names the object of a scene set's scenes (the identify stage's metrics)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from tqdm import tqdm

from tactile6d.estimation import identity_model
from tactile6d.estimation.identifier import Identifier
from tactile6d.evaluation import scoring
from tactile6d.evaluation.metric_table import ERROR_KEYS, HEADLINE_KEYS
from tactile6d.sim.scenes import scene_backgrounds


def identify_scene_set(identifier: Identifier, scenes: Mapping[str, np.ndarray],
                       references: Mapping[str, scoring.ObjectReference], desc: str = "identify") -> dict:
    """Identify every scene of a scene set (the ``scenes`` artifact's arrays) against the identifier's
    library, without telling it the object, and summarise (the identify stage's metrics):

    ``top1``, ``top3`` (shares of scenes whose true object came first / in the first three),
    ``top1_by_object``, ``confusion`` (``identity_model.confusion_matrix`` over the library's order),
    ``time_s_median`` and ``time_s_p90`` (seconds per identification), and ``pose_of_correct``: the
    ``metric_table.HEADLINE_KEYS`` of ``scoring.summarise_by_object`` over the scenes identified correctly (best
    poses, scored against references: name -> ``scoring.ObjectReference``). A progress bar on stderr.
    """
    objects = identifier.names
    truth, predicted, ranks, seconds, owners = [], [], [], [], []
    errors = {key: [] for key in ERROR_KEYS}
    for s in tqdm(range(len(scenes["names"])), desc=desc, unit="scene"):
        name = str(scenes["objects"][s])
        T_sensors = scenes["T_world_sensors"][s]
        result = identifier.identify(T_sensors, scenes["images"][s], scene_backgrounds(scenes, s))
        order = [o.name for o in result.objects]
        truth.append(objects.index(name))
        predicted.append(objects.index(order[0]))
        ranks.append(order.index(name))
        seconds.append(result.seconds["total"])
        if order[0] == name:
            poses = result.best.candidate.estimate.poses
            scored = scoring.scene_errors(poses, len(poses), scenes["T_world_object"][s], T_sensors,
                                             references[name].points, references[name].surface,
                                             tree=references[name].tree)
            for key in errors:
                errors[key].append(scored[key])
            owners.append(name)
    ranks = np.array(ranks)
    truth, predicted = np.array(truth, dtype=np.int64), np.array(predicted, dtype=np.int64)
    pose = {}
    if owners:
        average = scoring.summarise_by_object({k: np.array(v) for k, v in errors.items()}, np.array(owners))
        pose = {k: v for k, v in average["average"].items() if k in HEADLINE_KEYS}
    nan = float("nan")
    return {
        "objects": list(objects),
        "n_scenes": int(len(ranks)),
        "top1": float(np.mean(ranks == 0)) if len(ranks) else nan,
        "top3": float(np.mean(ranks < 3)) if len(ranks) else nan,
        "top1_by_object": {o: float(np.mean(predicted[truth == i] == i)) for i, o in enumerate(objects)
                           if np.any(truth == i)},
        "confusion": identity_model.confusion_matrix(truth, predicted, len(objects)).tolist(),
        "time_s_median": float(np.median(seconds)) if seconds else nan,
        "time_s_p90": float(np.percentile(seconds, 90)) if seconds else nan,
        "pose_of_correct": pose,
    }
