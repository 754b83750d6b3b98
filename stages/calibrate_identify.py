"""Stage calibrate_identify: the identification score's weights, fitted on the calibration scenes.

Every scene of the ``calibration`` set (``scenes.calibration``: generated like offaxis, with its own
seed; no other stage reads it) is screened against every object of the library, ``objects.names`` and
``identify.distractors`` (``Identifier.candidates``:
the images read once, each object estimated with ``identify.screen``), and the weights of the
conditional logit over the best poses' features are fitted by maximum likelihood
(``identity_model.fit_weights``). The test set never enters the calibration, and the validation and
offaxis figures of stage identify are on scenes the weights never saw. Writes
``artifacts/identify/calibration.json``: the feature names, the weights, the objects and scene set
used, and the fitted score's top-1 / top-3 accuracy on those same scenes (an optimistic figure; the
identify stage's figures on other sets are the honest ones).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tqdm import tqdm

from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json
from tactile6d.estimation import identity_model
from tactile6d.estimation.identifier import Identifier
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed

SCENE_SET = "calibration"
L2 = 1e-3  # ridge on the weights: keeps them finite when every true object already scores best


def main(argv: list[str] | None = None) -> int:
    _, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    artifacts = cfg.paths.artifacts_dir
    objects = [str(o) for o in cfg.objects.names]
    distractors = [str(o) for o in cfg.identify.distractors]
    scenes = read_artifact(layout.scenes_file(artifacts, SCENE_SET), "scenes")
    truth = np.array([objects.index(str(o)) for o in scenes["objects"]])
    t0 = time.perf_counter()
    features = []
    with Identifier.from_artifacts(objects, artifacts, cfg, calibrated=False, distractors=distractors) as identifier:
        for s in tqdm(range(len(truth)), desc=f"screening {SCENE_SET} x {len(identifier.names)} objects on "
                      f"{identifier.describe()}", unit="scene"):
            found, _ = identifier.candidates(scenes["T_world_sensors"][s], scenes["images"][s])
            features.append(np.stack([c.features for c in found]))
    features = np.stack(features)
    weights = identity_model.fit_weights(features, truth, L2)
    probabilities = identity_model.scores_to_probabilities(identity_model.features_to_scores(features, weights))
    rank_of_truth = (probabilities > probabilities[np.arange(len(truth)), truth][:, None]).sum(axis=1)
    out = {
        "features": list(identity_model.FEATURES),
        "weights": weights.tolist(),
        "objects": identifier.names,
        "scene_set": SCENE_SET,
        "n_scenes": int(len(truth)),
        "top1_on_calibration_scenes": float(np.mean(rank_of_truth == 0)),
        "top3_on_calibration_scenes": float(np.mean(rank_of_truth < 3)),
        "mean_log_likelihood": -identity_model.negative_log_likelihood(weights, features, truth),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    path = layout.identify_calibration_file(artifacts)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, out)
    print(f"weights {dict(zip(out['features'], np.round(weights, 4)))}; top-1 on {SCENE_SET} "
          f"{100 * out['top1_on_calibration_scenes']:.1f} % -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
