"""The figure functions draw headless and save PNGs of the expected size."""

import numpy as np
import pytest

from tactile6d.core.geometry import make_pose
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.evaluation import plots


@pytest.mark.slow
def test_figures_save(tmp_path):
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.05, 0.05, (300, 3))
    T = make_pose(np.eye(3), [0.1, 0, 0.2])
    sensors = T @ sensor_poses_touching(points[:3], np.eye(3), 0.0)
    drawn = {
        "pose": plots.poses_figure(points, T, T @ make_pose(np.eye(3), [0.01, 0, 0]), sensors, "t"),
        "omegas": plots.omegas_figure(points, [np.arange(10), np.arange(20, 40), np.array([5])], points[:3], "t"),
        "angles": plots.angle_maps_figure({"a": (points, rng.random(300)), "b": (points, rng.random(300))}),
        "count": plots.sensor_count_figure({"ours": {"L1": {"pos_err_cm_top1": 5.0, "contact_acc_top1": 10.0},
                                                   "L2": {"pos_err_cm_top1": 2.0, "contact_acc_top1": 50.0}}}, "t"),
    }
    for name, fig in drawn.items():
        path = tmp_path / f"{name}.png"
        fig.savefig(path, dpi=50)
        assert path.stat().st_size > 2000


def test_sensor_box_has_twelve_edges_of_the_right_lengths():
    edges = plots._box_edges(np.eye(4))
    lengths = sorted(np.round(np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1), 4).tolist())
    assert lengths == [0.027] * 4 + [0.0322] * 4 + [0.034] * 4
