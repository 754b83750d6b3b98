"""scripts/track_hypotheses.py: its per-frame line, against one written by hand."""

from script_loader import load_script

track_hypotheses = load_script("track_hypotheses")


def test_an_update_line_lists_the_hypotheses_followed():
    line = track_hypotheses.frame_line(7, "update", 0.4321, [(0.43, 0.0018), (3.5, 0.00201)])
    assert line == "  7 update     0.43 cm  followed (0.43 cm, 1.800) (3.50 cm, 2.010)"


def test_a_redetection_line_adds_what_the_estimate_offered():
    line = track_hypotheses.frame_line(30, "redetect", 3.5, [(3.5, 0.0018)], [(3.5, 0.0018), (0.7, 0.0019)], [0])
    assert line.endswith("re-detection ranked (3.50 cm, 1.800) (0.70 cm, 1.900), offered [0]")
