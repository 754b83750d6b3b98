"""The figure of one estimate (``tactile6d.evaluation.estimate_figure``): presses predicted at a pose on the image's
pixels, their agreement with the observed patches, and what the figure draws."""

import numpy as np
import pytest
import trimesh

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.core.sensor import sensor_poses_touching
from tactile6d.estimation import render_and_compare
from tactile6d.estimation.estimator import Estimate
from tactile6d.evaluation import estimate_figure as ef
from tactile6d.perception.contacts import Contacts
from tactile6d.sim import gel_press

T_TRUE = make_pose(rotvec_to_rotmat([0.2, -0.1, 0.3]), [0.1, 0.0, 0.2])
FACES = (np.array([[0.0, 0.0, 0.025], [0.06, 0.0, 0.0], [0.0, -0.04, 0.0]]),  # points, then outward normals
         np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]]))


@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box(extents=(0.12, 0.08, 0.05))


def sensors(depths=0.0015):
    """Three sensors pressing the box at T_TRUE on its top, end and side faces."""
    return T_TRUE @ sensor_poses_touching(*FACES, [0.0, 0.4, -1.0], depths)


def test_grid_to_image_repeats_each_cell_over_its_block_and_image_to_grid_undoes_it():
    grid = np.arange(2 * 80 * 60, dtype=np.float32).reshape(2, 80, 60)
    image = ef.grid_to_image(grid, 4)
    assert image.shape == (2, 320, 240)
    naive = np.empty_like(image)
    for r in range(320):
        for c in range(240):
            naive[:, r, c] = grid[:, r // 4, c // 4]
    assert np.array_equal(image, naive)
    assert np.array_equal(render_and_compare.image_to_grid(image, 4), grid)


def test_predicted_presses_are_the_gel_depths_on_the_images_pixels(box):
    T = sensors()
    presses = ef.predicted_presses(box, T_TRUE, T, step=4)
    assert presses.shape == (3, 320, 240) and presses.dtype == np.float32
    grid = gel_press.poses_to_gel_depths(box, T_TRUE, T, 4)[0]
    assert np.array_equal(render_and_compare.image_to_grid(presses, 4), grid)
    assert 0.001 < presses.max() < 0.002  # pressed about 1.5 mm


def test_press_agreement_is_one_at_the_pose_that_made_the_presses_and_falls_off_it(box):
    T = sensors(np.array([0.0015, 0.0015, -0.003]))  # the third sensor 3 mm off its face: lifted
    observed = ef.predicted_presses(box, T_TRUE, T, step=4) > 0
    assert observed[:2].any(axis=(1, 2)).all() and not observed[2].any()
    assert np.allclose(ef.press_agreement(observed, ef.predicted_presses(box, T_TRUE, T, step=4)), 1.0)
    slid = T_TRUE @ make_pose(np.eye(3), [0.004, 0.0, -0.0008])  # 4 mm along the top face, 0.8 mm out of it
    moved = ef.predicted_presses(box, slid, T, step=4)
    ious = ef.press_agreement(observed, moved)
    assert ious[0] < 0.6  # the top's patch moved and shrank (0.45)
    assert ious[1] < 0.8  # the end face pressed 4 mm deeper: a larger patch (0.70)
    assert np.count_nonzero(moved[1]) > 1.3 * np.count_nonzero(observed[1])
    assert ious[2] == 1.0  # still clear of the lifted sensor


def estimate_at(poses, T_world_sensors, masks=None, depths=None, distinct=None):
    """An Estimate holding what the figure reads (its selection is not drawn)."""
    L = len(T_world_sensors)
    contacts = Contacts(T_world_sensors[:, :3, 3], np.tile([0.0, 0.0, 1.0], (L, 1)), np.ones(L, bool), masks, depths)
    return Estimate(poses=poses, scores=np.zeros(len(poses)), losses=np.zeros(len(poses)),
                    penetrations=np.zeros((len(poses), L)), angles=None, contacts=contacts, selection=None,
                    n_hypotheses=len(poses), confidence=0.5 if distinct is not None else None, distinct=distinct)


@pytest.mark.slow
def test_the_figure_draws_the_object_and_each_sensors_presses_with_their_agreement(box):
    T = sensors()
    presses = ef.predicted_presses(box, T_TRUE, T)
    rival = T_TRUE @ make_pose(rotvec_to_rotmat([0.0, 0.0, np.pi]), [0.0, 0.0, 0.0])
    estimate = estimate_at(np.stack([T_TRUE, rival]), T, presses > 0, presses, distinct=np.array([0, 1]))
    images = np.full((3, 320, 240, 3), 100, np.uint8)
    fig = ef.estimate_figure(box.vertices, box, T, images, estimate, "a box")
    titles = [ax.get_title() for ax in fig.axes]
    assert titles.count("press read (mm)") == 3
    assert titles.count("at the best pose, IoU 1.00") == 3
    assert [t for t in titles if t.startswith("sensor")] == ["sensor 0: image", "sensor 1: image", "sensor 2: image"]
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert legend == ["best pose", "pose 1, about as good", "contacts read"]
    # The method read no image (the baseline): only the predicted presses, no agreement to give.
    plain = ef.estimate_figure(box.vertices, box, T, images, estimate_at(T_TRUE[None], T), "a box")
    plain_titles = [ax.get_title() for ax in plain.axes]
    assert plain_titles.count("at the best pose") == 3 and "press read (mm)" not in plain_titles
