"""scripts/compare_errors.py: paired differences of two runs' best-pose errors against a naive bootstrap."""

import numpy as np
import pytest
from script_loader import load_script

compare = load_script("compare_errors")


def test_the_paired_difference_is_a_naive_bootstraps():
    rng = np.random.default_rng(1)
    base = rng.gamma(1.0, 0.5, 40)
    other = base + rng.normal(-0.1, 0.2, 40)
    mean, low, high = compare.paired_difference(base, other, 500, np.random.default_rng(0))
    draws = np.random.default_rng(0).integers(0, 40, (500, 40))
    naive = [np.mean([other[i] - base[i] for i in row]) for row in draws]
    assert mean == pytest.approx(np.mean(other - base), abs=1e-12)
    assert low == pytest.approx(np.percentile(naive, 5), abs=1e-12)
    assert high == pytest.approx(np.percentile(naive, 95), abs=1e-12)
    assert low < mean < high


def test_scenes_without_an_estimate_are_left_out():
    mean, _, _ = compare.paired_difference(np.array([1.0, np.nan, 2.0]), np.array([1.5, 1.0, 2.5]), 10,
                                           np.random.default_rng(0))
    assert mean == pytest.approx(0.5)


def _run(tmp_path, name, position_m):
    path = tmp_path / f"{name}.npz"
    np.savez(path, objects=np.array(["a"] * len(position_m)), position=np.stack([position_m, position_m + 1], axis=1))
    return str(path)


def test_pairs_are_compared_in_cm_and_pooled_per_group(tmp_path, capsys):
    a1, b1 = _run(tmp_path, "a1", np.array([0.01, 0.02])), _run(tmp_path, "b1", np.array([0.02, 0.03]))
    a2, b2 = _run(tmp_path, "a2", np.array([0.01, 0.01])), _run(tmp_path, "b2", np.array([0.01, 0.01]))
    assert compare.main(["--base", a1, a2, "--other", b1, b2, "--groups", "x", "x", "--resamples", "50"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "per scene +1.000 cm" in out[0] and "per scene +0.000 cm" in out[1]
    assert out[2].startswith("x: 4 scenes") and "per scene +0.500 cm" in out[2]
    with pytest.raises(SystemExit, match="one of each per pair"):
        compare.main(["--base", a1, a2, "--other", b1])
