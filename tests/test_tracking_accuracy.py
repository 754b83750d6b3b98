"""tactile6d.evaluation.tracking_accuracy: the track's figures, each checked against a plain loop over the frames."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile6d.core import metrics
from tactile6d.evaluation import tracking_accuracy as acc


def longest_run_naive(flags) -> int:
    best = current = 0
    for flag in flags:
        current = current + 1 if flag else 0
        best = max(best, current)
    return best


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from([0.001, 0.03, np.nan]), max_size=40))
def test_longest_over_counts_the_longest_run_of_lost_frames(errors):
    expected = longest_run_naive([not (e <= 0.02) for e in errors]) / 30.0  # NaN: no pose, lost
    assert acc.longest_over(np.array(errors), 0.02, 30.0) == pytest.approx(expected)


def test_runs_are_the_stretches_of_true():
    flags = np.array([1, 1, 0, 1, 0, 0, 1, 1, 1], dtype=bool)
    assert acc.true_runs(flags).tolist() == [[0, 2], [3, 4], [6, 9]]
    assert acc.run_lengths(flags).tolist() == [2, 1, 3] and acc.run_lengths(np.zeros(3, bool)).size == 0


def test_frames_to_recover_waits_until_the_error_stays_under():
    errors = np.array([0.001, 0.05, 0.04, 0.001, 0.03, 0.002, 0.001])
    assert acc.frames_to_recover(errors, 1, 0.01) == 4  # frame 5 on: back, and stays
    assert acc.frames_to_recover(errors, 5, 0.01) == 0
    assert acc.frames_to_recover(np.array([0.001, 0.05]), 0, 0.01) is None


def test_trust_summary_sorts_the_frames_as_counted_by_hand():
    ambiguous = np.array([True, True, False, False, False, True])
    adi = np.array([0.02, 0.001, 0.002, 0.015, np.nan, 0.004])  # NaN: no pose, counted wrong
    confidence = np.array([0.3, 0.9, 0.95, np.nan, 0.2, 0.8])
    out = acc.trust_summary(ambiguous, confidence, adi)
    assert out["ambiguous_share"] == pytest.approx(3 / 6)
    assert out["wrong_share_ambiguous"] == pytest.approx(1 / 3)
    assert out["wrong_share_unambiguous"] == pytest.approx(2 / 3)
    # right frames with a confidence: 0.9, 0.95, 0.8; wrong ones: 0.3, 0.2
    assert out["confidence_auroc"] == pytest.approx(metrics.auroc([0.9, 0.95, 0.8], [0.3, 0.2])) and out[
        "confidence_auroc"] == 1.0


def test_trust_summary_without_flags_or_wrong_frames_says_none():
    out = acc.trust_summary(np.zeros(3, bool), np.array([0.9, 0.8, 0.7]), np.array([0.001, 0.002, 0.003]))
    assert out["ambiguous_share"] == 0.0 and np.isnan(out["wrong_share_ambiguous"])
    assert out["wrong_share_unambiguous"] == 0.0 and np.isnan(out["confidence_auroc"])


def test_failed_single_shot_frames_are_counted_and_left_out_of_its_figures():
    track = {"position": np.array([0.001, 0.002, 0.03, 0.004]), "adi": np.array([0.001, 0.002, 0.03, 0.004])}
    single = {"position": np.array([0.005, np.nan]), "adi": np.array([0.005, np.nan])}
    compared = np.array([0, 3])
    row = acc.summarise_sequence(track, single, compared, ["redetect", "update", "update", "update"],
                                 np.full(4, 0.01), 30.0, 0.02)
    assert row["single_failed"] == 1 and row["single_position_cm_median"] == pytest.approx(0.5)
    assert row["track_position_cm_median_compared"] == pytest.approx(0.25)
    summary = acc.summarise_set([row, row], np.concatenate([track["position"]] * 2),
                                np.concatenate([single["position"]] * 2), np.concatenate([track["position"][compared]] * 2))
    assert summary["single_failed"] == 2 and summary["single_position_cm_mean"] == pytest.approx(0.5)
