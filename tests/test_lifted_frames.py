"""scripts/lifted_frames.py: its per-group summary line, against numbers counted by hand."""

import numpy as np
from script_loader import load_script

lifted_frames = load_script("lifted_frames")


def test_a_group_line_counts_frames_failures_and_errors():
    line = lifted_frames.group_line("some not touching", [0.2, 1.5, 0.9, 3.0], 2, [0.9, 0.8, np.nan, 0.4],
                                    [0.1, 0.8, 0.5, 2.0])
    assert line.startswith("some not touching: 6 frames, 2 not estimated (NoMatch)")
    assert "median 1.20 cm, mean 1.40" in line and "2 of 4 1 cm or more off" in line
    assert "mean confidence 0.70 against 0.75 within 1 cm ADI" in line


def test_a_group_without_estimates_or_confidences_says_only_what_it_has():
    assert lifted_frames.group_line("all touching", [], 3, [], []) == "all touching: 3 frames, 3 not estimated (NoMatch)"
    assert "confidence" not in lifted_frames.group_line("all touching", [0.1], 0, [np.nan], [0.1])
