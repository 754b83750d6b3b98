"""scripts/track_frame_confidence.py: the tracker-state features of a frame, and the held-out fit."""

from types import SimpleNamespace

import numpy as np

from script_loader import load_script
from tactile6d.core.geometry import make_pose
from tactile6d.estimation import confidence
from tactile6d.estimation.tracker import _Hypothesis

track_frame_confidence = load_script("track_frame_confidence")
FEATURES = track_frame_confidence.FEATURES


def fake_tracker(hypotheses, since=4):
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # far apart: ADI = shift
    return SimpleNamespace(_hypotheses=hypotheses, _frames_since_redetect=since,
                           estimator=SimpleNamespace(spread_points=points))


def test_the_features_are_the_leaders_and_the_single_shot_ones_on_the_hypotheses():
    near = _Hypothesis([np.eye(4)], 0.002, (0.0005, 0.1, 0.0002))
    far = _Hypothesis([make_pose(np.eye(3), [0.03, 0.0, 0.0])], 0.003)
    tracker = fake_tracker([far, near])  # not in evidence order: the leader is the least evidence
    row = track_frame_confidence.tracker_features(tracker, 0.8)
    f = dict(zip(FEATURES, row))
    assert np.isclose(f["confidence"], np.log(0.8 / 0.2))
    expected = confidence.features(np.array([0.002, 0.003]), confidence.distances_from_best(
        tracker.estimator.spread_points, np.stack([np.eye(4), far.poses[-1]])))
    assert np.allclose([f["rival_gap"], f["spread_cm"]], expected)
    assert np.isclose(f["spread_cm"], 3.0)  # a 3 cm translation moves every point by 3 cm
    assert np.allclose([f["evidence_mm"], f["residual_mm"], f["agreement"], f["penetration_mm"]], [2.0, 0.5, 0.1, 0.2])
    assert f["hypotheses"] == 2 and f["frames_since"] == 4


def test_a_frame_without_hypotheses_or_confidence_has_no_values_but_the_counts():
    row = track_frame_confidence.tracker_features(fake_tracker([], since=0), None)
    assert np.isnan(row[:7]).all() and row[7] == 0 and row[8] == 0


def test_a_feature_that_tells_right_from_wrong_is_found_on_every_set_and_noise_is_not():
    rng = np.random.default_rng(1)
    sets = {}
    for name in ("a", "b"):
        right = rng.random(400) < 0.7
        x = np.full((400, len(FEATURES)), np.nan)
        x[:, 0] = rng.normal(size=400)  # the confidence: noise here
        x[:, 2] = np.where(right, 0.2, 3.0) + rng.normal(scale=0.1, size=400)  # spread_cm: small when right
        sets[name] = (x, right)
    alone = track_frame_confidence.held_out_aurocs(sets, [0])
    both = track_frame_confidence.held_out_aurocs(sets, [0, FEATURES.index("spread_cm")])
    for fit in ("a", "b"):
        assert all(abs(v - 0.5) < 0.1 for v in alone[fit].values())
        assert all(v > 0.99 for v in both[fit].values())
