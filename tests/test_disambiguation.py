"""tactile6d.estimation.disambiguation: where to touch to tell poses apart, and the poses told apart (choose)."""

import warnings

import numpy as np
import pytest
import trimesh

from tactile6d.core import geometry as g
from tactile6d.core.sensor import bodies_overlap, sensor_poses_touching
from tactile6d.estimation import disambiguation
from tactile6d.perception.contacts import UntouchedSensorWarning
from tactile6d.sim.scenes import body_penetrates
from tactile6d.sim import surface_sampling
from tactile6d.sim.render import DigitRenderer
from tactile6d.sim.surface_sampling import sample_surface

HALF = np.array([0.05, 0.03, 0.02])  # m, the box's half extents: 10 x 6 x 4 cm
BEST = g.make_pose(np.eye(3), [0.3, 0.0, 0.1])
SHIFTED = BEST @ g.make_pose(np.eye(3), [0.03, 0.0, 0.0])  # the rival: 3 cm along the box's long axis


@pytest.fixture(scope="module")
def box():
    return sample_surface(trimesh.creation.box(extents=2 * HALF))


def local(T_world_object, point):
    return g.transform_points(g.invert_pose(T_world_object), np.asarray(point)[None])[0]


def test_a_box_slid_along_its_length_is_told_apart_on_an_end_face(box):
    """Slid 3 cm along x, the rival leaves its top, bottom and sides where the best pose has them (nothing to
    tell there); only the end faces differ: the touch is on one, at least 1 cm (``enough``) from the rival's
    surface, its normal the end face's, its sensor clear of the box."""
    touch = disambiguation.touch_to_tell_apart(box, np.stack([BEST, SHIFTED]), np.zeros((0, 4, 4)))
    assert touch is not None
    p = local(BEST, touch.point)
    assert abs(abs(p[0]) - HALF[0]) < 1e-6 and np.all(np.abs(p[1:]) < HALF[1:])  # on an end face
    assert abs(abs(touch.normal[0]) - 1.0) < 1e-9 and np.sign(touch.normal[0]) == np.sign(p[0])
    assert touch.separation >= 0.01 and touch.tells_apart
    nearest = np.min(np.linalg.norm(g.transform_points(SHIFTED, box.points) - touch.point, axis=1))
    assert nearest == pytest.approx(touch.separation)
    assert not body_penetrates(box, g.invert_pose(BEST) @ touch.T_world_sensor)
    expected = BEST @ sensor_poses_touching(p[None], np.array([[np.sign(p[0]), 0.0, 0.0]]), 0.0, 0.0018)[0]
    np.testing.assert_allclose(touch.T_world_sensor[:3, 3], expected[:3, 3], atol=1e-9)


@pytest.mark.slow
def test_the_touch_keeps_clear_of_the_sensors_already_there(box):
    """A sensor on the -x end face already: the touch goes to the other end."""
    first = disambiguation.touch_to_tell_apart(box, np.stack([BEST, SHIFTED]), np.zeros((0, 4, 4)))
    occupied = first.T_world_sensor[None]
    second = disambiguation.touch_to_tell_apart(box, np.stack([BEST, SHIFTED]), occupied)
    assert np.sign(local(BEST, second.point)[0]) == -np.sign(local(BEST, first.point)[0])
    assert not bodies_overlap(second.T_world_sensor, occupied[0], -0.003)


def test_poses_that_no_touch_tells_apart_get_the_flattest_reachable_touch(box):
    """A rival 1 mm off everywhere: no point lies ``least`` (3 mm) from its surface, so the touch is the flattest
    reachable spot (on a box, the middle of a face), its separation under ``least``."""
    near = BEST @ g.make_pose(np.eye(3), [0.001, 0.0, 0.0])
    touch = disambiguation.touch_to_tell_apart(box, np.stack([BEST, near]), np.zeros((0, 4, 4)))
    assert touch is not None and touch.separation < 0.003 and not touch.tells_apart
    p = local(BEST, touch.point)
    on_face = np.abs(np.abs(p) - HALF) < 1e-6
    assert on_face.sum() == 1 and np.all(np.abs(p[~on_face]) < HALF[~on_face] - 0.006)  # 6 mm from every edge
    with pytest.raises(ValueError, match="at least one rival"):
        disambiguation.touch_to_tell_apart(box, BEST[None], np.zeros((0, 4, 4)))


def test_separation_and_flatness_against_naive_loops(box):
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.1, 0.1, (20, 3)) + BEST[:3, 3]
    rivals = np.stack([SHIFTED, BEST @ g.make_pose(g.rotvec_to_rotmat([0.0, 0.0, np.pi / 2]), [0.0, 0.0, 0.0])])
    naive = [min(np.min(np.linalg.norm(g.transform_points(T, box.points) - p, axis=1)) for T in rivals) for p in points]
    np.testing.assert_allclose(disambiguation.separation_from_rivals(points, box, rivals), naive)
    indices = rng.choice(len(box.points), 30, replace=False)
    naive_flat = []
    for i in indices:  # every sample within 6 mm, by brute force
        near = np.linalg.norm(box.points - box.points[i], axis=1) <= 0.006
        naive_flat.append(np.min(box.normals[near] @ box.normals[i]))
    np.testing.assert_allclose(disambiguation.flatness(box, indices, 0.006), naive_flat)


@pytest.mark.slow
def test_a_guarded_move_meets_the_object_where_it_is(box):
    """A touch placed by the slid pose, on its end face: moving in along the approach line the sensor meets the
    box where the box really is: at the touch where the slid pose is right; 3 cm further in, on the true end face,
    where it is not and the travel (2 x 4 cm) reaches that far; nowhere when the box is elsewhere."""
    touch = disambiguation.touch_to_tell_apart(box, np.stack([SHIFTED, BEST]), np.zeros((0, 4, 4)))
    at_touch, met = disambiguation.touch_as_met(box.mesh, SHIFTED, touch, reach=0.04)
    assert met
    np.testing.assert_allclose(at_touch, touch.T_world_sensor, atol=1e-9)
    true_met, met = disambiguation.touch_as_met(box.mesh, BEST, touch, reach=0.04)
    assert met
    gel = lambda T: local(BEST, g.transform_points(T, [[0.0, 0.0, 0.0]])[0])  # the sensor's origin, box frame
    assert np.linalg.norm(gel(true_met) - gel(at_touch)) == pytest.approx(0.03, abs=1e-6)  # 3 cm along x
    far = g.make_pose(np.eye(3), [5.0, 0.0, 0.0])
    elsewhere, met = disambiguation.touch_as_met(box.mesh, far, touch)
    assert not met and np.array_equal(elsewhere, touch.T_world_sensor)


@pytest.fixture(scope="module")
def pressed(box):
    """The box at BEST pressed 1.8 mm on its top, bottom and +y side, within 1 cm of its middle: where the box
    slid 3 cm along x (SHIFTED) has the same faces, so those three touches cannot tell the two apart. Their images
    rendered over a flat no-contact colour, and an estimator of the box (test_tracker.make_estimator)."""
    from test_tracker import NO_CONTACT, make_estimator

    points, normals, _ = surface_sampling.sample_surface_even(box.mesh, 600, np.random.default_rng(0))
    world = {"mesh": box.mesh, "surface": box, "points": points, "normals": normals}
    on_box = np.array([[0.0, 0.0, HALF[2]], [0.005, 0.0, -HALF[2]], [-0.005, HALF[1], 0.0]])
    outward = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    T_sensors = BEST @ sensor_poses_touching(on_box, outward, 0.0, 0.0018)
    renderer = DigitRenderer.from_default_config(np.ascontiguousarray(NO_CONTACT[..., ::-1]), workers=1)
    images = np.stack([renderer.render(box.mesh, BEST, T, i).image for i, T in enumerate(T_sensors)])
    return make_estimator(world), T_sensors, images, renderer


@pytest.mark.slow
def test_a_touch_where_the_poses_differ_tells_them_apart(box, pressed):
    """The box slid 3 cm explains the three touches as well as the truth does; sent where the two differ (as the
    slid pose places the box: the estimate may rank the wrong one first), moved in until it meets the box and its
    image rendered there, a fourth sensor makes the truth win by a margin the three did not give."""
    estimator, T_sensors, images, renderer = pressed
    poses = np.stack([SHIFTED, BEST])
    three = disambiguation.choose(estimator, poses, T_sensors, images)
    touch = disambiguation.touch_to_tell_apart(box, poses, T_sensors)
    assert touch is not None and touch.separation >= 0.01
    T_fourth, met = disambiguation.touch_as_met(box.mesh, BEST, touch)
    fourth = renderer.render(box.mesh, BEST, T_fourth, 3).image
    with warnings.catch_warnings():
        warnings.simplefilter("error", UntouchedSensorWarning)  # a touch that meets nothing is no surprise here
        four = disambiguation.choose(estimator, poses, np.concatenate([T_sensors, T_fourth[None]]),
                                     np.concatenate([images, fourth[None]]))
    assert list(four.order) == [1, 0], (four.scores, met)
    assert np.linalg.norm(four.best[:3, 3] - BEST[:3, 3]) < 0.005
    margin = lambda c: c.scores[list(c.order).index(0)] - c.scores[list(c.order).index(1)]  # slid minus truth
    assert margin(four) > margin(three) + 0.001, (margin(four), margin(three))
    with pytest.raises(Exception, match="shape"):
        disambiguation.choose(estimator, np.eye(4), T_sensors, images)


def test_the_study_script_summarises_before_and_after_each_touch():
    """scripts/touch_to_tell_apart.py: over the ambiguous scenes, mean and median positional error (cm) and the
    count 1 cm ADI or more off, before and after each kind of touch, and how many touches were made."""
    from script_loader import load_script

    study = load_script("touch_to_tell_apart")
    rows = [{"before_position": 0.03, "before_adi": 0.012, "informed_position": 0.001, "informed_adi": 0.002,
             "informed_touched": True, "flat_position": 0.03, "flat_adi": 0.012, "flat_touched": True},
            {"before_position": 0.002, "before_adi": 0.003, "informed_position": 0.004, "informed_adi": 0.01,
             "informed_touched": False, "flat_position": 0.002, "flat_adi": 0.003, "flat_touched": True}]
    out = study.summary(rows)
    assert out["ambiguous"] == 2
    assert out["before"] == {"mean_cm": pytest.approx(1.6), "median_cm": pytest.approx(1.6), "wrong": 1}
    assert out["informed"] == {"mean_cm": pytest.approx(0.25), "median_cm": pytest.approx(0.25), "wrong": 1,
                               "touched": 1}
    assert out["flat"]["wrong"] == 1 and out["flat"]["touched"] == 2
    error = study.hand_error(np.random.default_rng(0), 0.0015, np.radians(1.5))
    assert g.is_rotation(error[:3, :3]) and 0 < np.linalg.norm(error[:3, 3]) < 0.01
