"""tactile6d.evaluation.symmetry: which poses the touched surface cannot tell from the truth."""

import numpy as np
import pytest
import trimesh

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.evaluation import symmetry
from script_loader import load_script


def turn(axis, deg, about=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A turn by deg about the line through ``about`` along ``axis`` (4, 4)."""
    R = rotvec_to_rotmat(np.radians(deg) * np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis))
    about = np.asarray(about, dtype=np.float64)
    return make_pose(R, about - R @ about)


@pytest.fixture(scope="module")
def off_centre_box():
    """A 10 x 6 x 3 cm box whose centre sits 1 cm from its frame's origin along y, as a YCB box's mesh may."""
    box = trimesh.creation.box((0.10, 0.06, 0.03))
    box.apply_translation((0.0, 0.01, 0.0))
    return box


@pytest.fixture(scope="module")
def mug():
    """A cylinder (radius 3 cm, 10 cm tall, on the z axis) with a 3 x 1.5 x 6 cm handle beside it at +x."""
    body = trimesh.creation.cylinder(radius=0.03, height=0.10, sections=128)
    handle = trimesh.creation.box((0.03, 0.015, 0.06))
    handle.apply_translation((0.043, 0.0, 0.0))
    return trimesh.util.concatenate([body, handle])


def test_on_surface_against_the_distance_along_a_face_normal(off_centre_box):
    """Points pushed out of the +x face (at x = 5 cm) by 0.5 and 2 mm: within and beyond 1 mm."""
    face = np.array([[0.05, 0.01, 0.0], [0.05, 0.02, 0.005]])
    assert symmetry.on_surface(off_centre_box, face + [0.0005, 0, 0]).tolist() == [True, True]
    assert symmetry.on_surface(off_centre_box, face + [0.002, 0, 0]).tolist() == [False, False]


def test_a_box_turned_about_its_centre_is_its_own_symmetry_yet_its_origin_moves(off_centre_box):
    samples = symmetry.surface_samples(off_centre_box, 1500)
    truth = make_pose(rotvec_to_rotmat([0.2, -0.1, 0.4]), [0.3, 0.1, 0.2])
    flipped = truth @ turn((0, 0, 1), 180.0, about=(0.0, 0.01, 0.0))
    D = symmetry.relative_pose(flipped, truth)
    assert np.allclose(D, turn((0, 0, 1), 180.0, about=(0.0, 0.01, 0.0)))
    assert symmetry.surface_share(off_centre_box, samples, D) > 0.99
    assert 100 * np.linalg.norm(flipped[:3, 3] - truth[:3, 3]) == pytest.approx(2.0)  # what the metric counts
    # The same turn about the frame's origin puts the box 2 cm along y: its ends leave the surface and the
    # faces along y overlap themselves by 2/3 only (about half of the area in all).
    assert symmetry.surface_share(off_centre_box, samples, turn((0, 0, 1), 180.0)) < 0.6
    assert symmetry.confusion_kind(1.0, 1.0) == "object symmetry"


def test_a_slide_along_the_faces_is_not_a_symmetry_of_the_box(off_centre_box):
    samples = symmetry.surface_samples(off_centre_box, 1500)
    share = symmetry.surface_share(off_centre_box, samples, make_pose(np.eye(3), [0.02, 0.0, 0.0]))
    assert 0.3 < share < symmetry.ALIKE_SHARE  # the four faces along x slide over themselves, the ends do not


def test_a_mug_turned_about_its_body_is_alike_only_where_the_handle_is_not_touched(mug):
    samples = symmetry.surface_samples(mug, 3000)
    D = turn((0, 0, 1), 90.0)  # about the body's axis: the handle moves from +x to +y
    whole = symmetry.surface_share(mug, samples, D)
    on_body = symmetry.contact_share(mug, samples, D, np.array([[-0.03, 0.0, 0.02], [0.0, -0.03, -0.02]]),
                                     radius=0.015)
    at_handle = symmetry.contact_share(mug, samples, D, np.array([[0.058, 0.0, 0.0]]), radius=0.015)
    assert whole < symmetry.ALIKE_SHARE and on_body > 0.97 and at_handle < 0.5
    assert symmetry.confusion_kind(whole, on_body) == "alike where touched"
    assert symmetry.confusion_kind(whole, at_handle) == "other"


def test_no_samples_near_the_contacts_give_nan(mug):
    samples = symmetry.surface_samples(mug, 500)
    assert np.isnan(symmetry.contact_share(mug, samples, np.eye(4), np.array([[1.0, 1.0, 1.0]])))


def test_the_scripts_rotation_angle_and_axis():
    script = load_script("symmetric_confusions")
    D = turn((0.0, 0.6, 0.8), 170.0, about=(0.01, 0.0, 0.0))
    assert script.rotation_deg(D) == pytest.approx(170.0)
    assert np.allclose(np.abs(script.rotation_axis(D)), [0.0, 0.6, 0.8])
