import numpy as np
import pytest

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import make_pose, random_rotations
from tactile6d.data.bop import (
    BOP_HEADER,
    YCBV_OBJ_IDS,
    BopRow,
    csv_to_rows,
    object_name_to_bop_id,
    read_bop_csv,
    rows_to_csv,
    write_bop_csv,
)

# 90 degrees about z: a non-symmetric rotation, so that a column-major file would read back as its transpose.
RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
GOOD_LINE = "1,2,5,0.9,0 -1 0 1 0 0 0 0 1,100 -200 300,0.5"


def random_rows(n=5, seed=0):
    rng = np.random.default_rng(seed)
    T = make_pose(random_rotations(n, rng), rng.uniform(-0.5, 0.5, size=(n, 3)))
    return [BopRow(scene_id=48 + k // 2, im_id=k, obj_id=k + 1, score=float(rng.uniform()), T=T[k],
                   time=-1.0 if k == 0 else 0.25 * k) for k in range(n)]


def test_round_trip_keeps_every_field(tmp_path):
    rows = random_rows()
    path = write_bop_csv(tmp_path / "tactile6d_ycbv-test.csv", rows)
    back = read_bop_csv(path)
    assert len(back) == len(rows)
    for row, got in zip(rows, back):
        assert (got.scene_id, got.im_id, got.obj_id, got.score, got.time) == (
            row.scene_id, row.im_id, row.obj_id, row.score, row.time)
        np.testing.assert_allclose(got.T, row.T, atol=1e-12)
    assert path.read_text().splitlines()[0] == BOP_HEADER
    assert path.read_text().splitlines()[1].endswith(",-1")  # unknown time


def test_translation_is_millimetres_and_rotation_row_major():
    row = BopRow(scene_id=3, im_id=7, obj_id=5, score=1.0, T=make_pose(RZ90, [0.1, -0.2, 0.3]), time=0.5)
    line = rows_to_csv([row]).splitlines()[1]
    scene_id, im_id, obj_id, score, R, t, time = line.split(",")
    assert (scene_id, im_id, obj_id, time) == ("3", "7", "5", "0.5")
    np.testing.assert_allclose([float(v) for v in R.split(" ")], [0, -1, 0, 1, 0, 0, 0, 0, 1])
    np.testing.assert_allclose([float(v) for v in t.split(" ")], [100.0, -200.0, 300.0], rtol=1e-12)
    # and a file written by another tool reads the same way
    (got,) = csv_to_rows(f"{BOP_HEADER}\n{GOOD_LINE}\n")
    np.testing.assert_array_equal(got.T[:3, :3], RZ90)
    np.testing.assert_allclose(got.T[:3, 3], [0.1, -0.2, 0.3], rtol=1e-12)
    assert (got.scene_id, got.im_id, got.obj_id, got.score, got.time) == (1, 2, 5, 0.9, 0.5)


def test_precision_is_enough_for_small_differences():
    T = make_pose(random_rotations(1, np.random.default_rng(1))[0], [0.123456789, 1e-7, -0.9876543])
    (got,) = csv_to_rows(rows_to_csv([BopRow(0, 0, 1, 0.5, T)]))
    assert np.abs(got.T[:3, 3] - T[:3, 3]).max() * 1000 < 1e-4  # mm
    assert np.abs(got.T[:3, :3] - T[:3, :3]).max() < 1e-6


@pytest.mark.parametrize(
    "text, message",
    [
        ("scene_id,im_id,obj_id,score,R,t\n" + GOOD_LINE, r"line 1: the header must be"),
        (f"{BOP_HEADER}\n{GOOD_LINE}\n1,2,5,0.9,0 -1 0 1 0 0 0 0 1,100 -200 300", r"line 3: 6 comma-separated fields"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0,100 -200 300,0.5", r"line 2: R must be 9 numbers"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0  1,100 -200 300,0.5", r"line 2: R must be 9 numbers"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -2 0 2 0 0 0 0 2,100 -200 300,0.5", r"line 2: R is not a rotation matrix"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0 -1,100 -200 300,0.5", r"line 2: R is not a rotation matrix"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0 1.001,100 -200 300,0.5", r"line 2: R is not a rotation matrix"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0 1,100 -200,0.5", r"line 2: t must be 3 numbers"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0 1,100 nan 300,0.5", r"line 2: t holds NaN"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0 1,100 x 300,0.5", r"line 2: t holds a value that is not a number"),
        (f"{BOP_HEADER}\n1,2.0,5,0.9,0 -1 0 1 0 0 0 0 1,100 -200 300,0.5", r"line 2: im_id '2.0' is not"),
        (f"{BOP_HEADER}\n-1,2,5,0.9,0 -1 0 1 0 0 0 0 1,100 -200 300,0.5", r"line 2: scene_id '-1' is not"),
        (f"{BOP_HEADER}\n1,2,x,0.9,0 -1 0 1 0 0 0 0 1,100 -200 300,0.5", r"line 2: obj_id 'x' is not"),
        (f"{BOP_HEADER}\n1,2,5,inf,0 -1 0 1 0 0 0 0 1,100 -200 300,0.5", r"line 2: score 'inf' is not finite"),
        (f"{BOP_HEADER}\n1,2,5,0.9,0 -1 0 1 0 0 0 0 1,100 -200 300,-2", r"line 2: time -2.0 is neither"),
        (f"{BOP_HEADER}\n{GOOD_LINE}\n1,2,6,0.9,0 -1 0 1 0 0 0 0 1,100 -200 300,0.7", r"line 3: time 0.7 differs"),
        (f"{BOP_HEADER}\n{GOOD_LINE}\n\n{GOOD_LINE}\n", r"line 3: 1 comma-separated fields"),
    ],
)
def test_each_rule_rejects_a_bad_file_naming_the_line(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=r"bad\.csv: " + message):
        read_bop_csv(path)


def test_good_file_passes_and_trailing_newlines_are_fine(tmp_path):
    path = tmp_path / "ok.csv"
    path.write_text(f"{BOP_HEADER}\n{GOOD_LINE}\n1,2,6,0.9,1 0 0 0 1 0 0 0 1,0 0 0,0.5\n\n")
    assert [r.obj_id for r in read_bop_csv(path)] == [5, 6]


def test_missing_file_is_named(tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv not found"):
        read_bop_csv(tmp_path / "nope.csv")


def test_writing_refuses_a_failed_estimate():
    T = np.full((4, 4), np.nan)
    with pytest.raises(InputError, match=r"BOP row 1: T is not a finite rigid transform"):
        rows_to_csv([random_rows(1)[0], BopRow(0, 1, 1, 0.5, T)])
    with pytest.raises(InputError, match=r"BOP row 0: obj_id -3"):
        rows_to_csv([BopRow(0, 1, -3, 0.5, np.eye(4))])


def test_object_ids():
    assert len(YCBV_OBJ_IDS) == 21 and sorted(YCBV_OBJ_IDS.values()) == list(range(1, 22))
    assert object_name_to_bop_id("002_master_chef_can") == 1
    assert object_name_to_bop_id("006_mustard_bottle") == 5
    assert object_name_to_bop_id("061_foam_brick") == 21
    assert object_name_to_bop_id("006_mustard_bottle", explicit_id=30) == 30  # explicit wins
    assert object_name_to_bop_id("prim_box", explicit_id=7) == 7
    with pytest.raises(InputError, match=r"'prim_box' is not one of the 21 BOP YCB-V objects.*pass its BOP obj_id"):
        object_name_to_bop_id("prim_box")
    with pytest.raises(InputError, match=r"must be a non-negative integer"):
        object_name_to_bop_id("prim_box", explicit_id=-1)
