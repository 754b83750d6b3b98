"""stages/evaluate_tracking.py: which sensor poses the tracker and the single-shot estimates are fed."""

import numpy as np
import pytest

from stages import evaluate_tracking
from tactile6d.core.config import compose_config


class RecordingEstimator:
    """Stands in for an Estimator: records the sensor poses of each call, answers the identity pose."""

    def __init__(self):
        self.calls = []

    def estimate(self, T, images):
        self.calls.append(np.asarray(T))

        class Answer:
            best = np.eye(4)
        return Answer()


@pytest.mark.parametrize("true_poses", [False, True])
def test_single_shot_frames_get_the_poses_the_setting_names(monkeypatch, true_poses):
    F, L = 6, 3
    reported = np.broadcast_to(np.eye(4), (1, F, L, 4, 4)).copy()
    true = reported.copy()
    true[..., 0, 3] = 0.01  # 1 cm apart, so that the two are told apart
    art = {"objects": np.array(["prim_box"]), "T_world_sensors": reported, "T_world_sensors_true": true,
           "images": np.zeros((1, F, L, 2, 2, 3), np.uint8)}
    estimator = RecordingEstimator()
    monkeypatch.setattr(evaluate_tracking, "_sequences", lambda artifacts: art)
    monkeypatch.setattr(evaluate_tracking, "_estimator", lambda cfg, obj: estimator)
    cfg = compose_config([f"track.evaluation.true_sensor_poses={true_poses}", "track.evaluation.single_shot_every=2"])
    out = evaluate_tracking.run_task("single", 0, cfg)
    assert out["frames"].tolist() == [0, 2, 4]
    expected = (true if true_poses else reported)[0, [0, 2, 4]]
    np.testing.assert_array_equal(np.stack(estimator.calls), expected)
