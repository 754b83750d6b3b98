"""tactile6d.evaluation.stream_figure: the figure of ``tactile6d track --plot`` (the CLI's own test draws it too)."""

import numpy as np
import pytest

from tactile6d.core import geometry as g
from tactile6d.evaluation.stream_figure import poses_to_motion, stream_figure


def a_stream(n=6):
    """n poses turning about z by 2 deg and moving 1 mm along x a frame; frame 0 without a pose."""
    poses = np.stack([g.make_pose(g.axis_angle_to_rotmat(np.array([0.0, 0.0, 1.0]), np.radians(2.0 * k)),
                                  [0.1 + 0.001 * k, 0.0, 0.2]) for k in range(n)])
    poses[0] = np.nan
    return poses


def test_motion_is_measured_from_the_first_frame_with_a_pose():
    offsets, turns = poses_to_motion(a_stream())
    assert np.isnan(offsets[0]).all() and np.isnan(turns[0])
    np.testing.assert_allclose(offsets[1:, 0], 0.001 * np.arange(5), atol=1e-12)
    np.testing.assert_allclose(offsets[1:, 1:], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.degrees(turns[1:]), 2.0 * np.arange(5), atol=1e-5)


def test_no_pose_at_all_gives_nan_everywhere():
    offsets, turns = poses_to_motion(np.full((3, 4, 4), np.nan))
    assert np.isnan(offsets).all() and np.isnan(turns).all()


@pytest.mark.parametrize("confidence", [np.full(6, np.nan), np.linspace(0.2, 0.9, 6)])
def test_the_figure_draws_what_it_is_given(confidence):
    modes = ["redetect", "update", "update", "hold", "redetect", "update"]
    fig = stream_figure(np.arange(6) / 30.0, a_stream(), modes, confidence, np.array([0, 1, 1, 0, 0, 0], bool),
                        np.array([3, 3, 2, 0, 3, 3]), "my_mug")
    position, turn, trust = fig.axes[:3]
    assert len(fig.axes) == (3 if np.isnan(confidence).all() else 4)  # the confidence's own axis when there is one
    np.testing.assert_allclose(position.lines[0].get_ydata()[1:], np.arange(5), atol=1e-9)  # x, mm
    np.testing.assert_allclose(turn.lines[0].get_ydata()[1:], 2.0 * np.arange(5), atol=1e-5)  # deg
    ticks = {tuple(line.get_xdata()) for line in turn.lines[1:]}
    assert ticks == {(0.0, 4 / 30.0), (3 / 30.0,)}  # re-detections, held
    assert "2 re-detections" in fig.texts[0].get_text() and "2 ambiguous" in fig.texts[0].get_text()
