"""scripts/compare_tracking.py: two evaluate_tracking runs compared sequence by sequence."""

import json

import numpy as np
import pytest
from script_loader import load_script

compare = load_script("compare_tracking")


def _metrics(tmp_path, name, errors_m, longest_over_s, names=None):
    """An evaluate_tracking metrics file holding what the script reads: per sequence its name and longest run over
    the lost threshold, per frame its tracked positional error (m)."""
    names = names or [f"obj_{q}/sequence_{q}" for q in range(len(errors_m))]
    metrics = {"sequences": [{"name": n, "longest_over_s": s} for n, s in zip(names, longest_over_s)],
               "frames": [{"track_position_m": list(e)} for e in errors_m], "summary": {}}
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(metrics))
    return str(path)


def test_a_run_is_read_in_cm_per_sequence(tmp_path):
    run = compare.TrackingRun.read(_metrics(tmp_path, "a", [[0.01, 0.03, 0.02], [0.05]], [0.0, 0.7]))
    np.testing.assert_allclose(run.per_sequence(np.mean), [2.0, 5.0])
    np.testing.assert_allclose(run.per_sequence(np.median), [2.0, 5.0])
    assert run.lost(0.5) == [("obj_1/sequence_1", 0.7)] and run.lost(0.7) == []
    assert run.summary() == "2.50 (2.75)"  # over all four frames


def test_sequences_are_paired_and_pooled_over_the_runs(tmp_path, capsys):
    a1 = _metrics(tmp_path, "a1", [[0.01, 0.01], [0.02, 0.02]], [0.0, 0.8])
    b1 = _metrics(tmp_path, "b1", [[0.02, 0.02], [0.02, 0.02]], [0.0, 0.3])
    a2 = _metrics(tmp_path, "a2", [[0.01, 0.01]], [1.0])
    b2 = _metrics(tmp_path, "b2", [[0.01, 0.01]], [2.0])
    assert compare.main(["--base", a1, a2, "--other", b1, b2, "--resamples", "50"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "over 0.5 s: none against obj_1/sequence_1 0.80 s" in out[0]
    assert "over 0.5 s: obj_0/sequence_0 2.00 s against obj_0/sequence_0 1.00 s" in out[1]
    assert out[2] == "all: 1 of 3 over 0.5 s, 2.0 s in all against 2 of 3 over 0.5 s, 1.8 s in all"
    # per sequence, other minus base: +1, 0, 0 cm
    assert out[3].startswith("all: per sequence, mean over frames +0.333 cm [")
    assert out[4].startswith("all: per sequence, median over frames +0.333 cm [")


def test_other_sequences_or_unpaired_files_are_refused(tmp_path):
    a = _metrics(tmp_path, "a", [[0.01]], [0.0])
    b = _metrics(tmp_path, "b", [[0.01]], [0.0], names=["another/sequence_0"])
    with pytest.raises(SystemExit, match="hold other sequences"):
        compare.main(["--base", a, "--other", b])
    with pytest.raises(SystemExit, match="one of each per pair"):
        compare.main(["--base", a, a, "--other", b])
