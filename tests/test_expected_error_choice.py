"""scripts/expected_error_choice.py: the pose of least expected positional error, against a naive loop."""

import numpy as np
import pytest

from script_loader import load_script


def naive_choice(translations, scores, tau):
    best, best_risk = None, np.inf
    weights = [np.exp(-(s - min(scores)) / tau) for s in scores]
    for i, ti in enumerate(translations):
        risk = sum(w * np.linalg.norm(np.subtract(ti, tj)) for w, tj in zip(weights, translations)) / sum(weights)
        if risk < best_risk:
            best, best_risk = i, risk
    return best


@pytest.mark.parametrize("seed", range(5))
def test_against_a_naive_loop(seed):
    rng = np.random.default_rng(seed)
    t, s = rng.normal(0, 0.02, (12, 3)), rng.uniform(0.0005, 0.003, 12)
    for tau in (1e-5, 2e-4, 1e-2):
        assert load_script("expected_error_choice").expected_error_choice(t, s, tau) == naive_choice(t, s, tau)


def test_a_small_tau_keeps_the_best_scored_and_a_ring_of_equals_gives_its_middle():
    script = load_script("expected_error_choice")
    # Five poses on an arc of a pitcher's origin turned about its body (radius 2 cm), scored alike.
    angles = np.radians([-60, -30, 0, 30, 60])
    t = 0.02 * np.stack([np.cos(angles), np.sin(angles), np.zeros(5)], axis=1)
    s = np.array([0.00050, 0.00052, 0.00053, 0.00051, 0.00052])
    assert script.expected_error_choice(t, s, 1e-6) == 0
    assert script.expected_error_choice(t, s, 2e-4) == 2


def test_the_bootstrap_interval_holds_the_mean():
    low, high = load_script("expected_error_choice").bootstrap_interval(np.linspace(-1.0, 0.5, 40))
    assert low < -0.25 < high and high - low < 0.5
