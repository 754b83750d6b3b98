import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile6d.core import geometry as g
from tactile6d.core import metrics as M


def _pose(rotvec, t):
    return g.make_pose(g.rotvec_to_rotmat(np.asarray(rotvec, dtype=float)), np.asarray(t, dtype=float))


def test_positional_error_batched():
    T_gt = _pose([0.1, 0.2, 0.3], [0.1, 0.0, 0.2])
    T_est = np.stack([T_gt, _pose([0, 0, 1], [0.1, 0.03, 0.24])])
    np.testing.assert_allclose(M.positional_error(T_est, T_gt), [0.0, 0.05], atol=1e-15)


def test_adi_by_hand():
    # Two points 1 cm apart on x; the estimate is shifted 7 mm along x: the moved points are at
    # 7 mm (nearest true point 10 mm, 3 mm away) and 17 mm (nearest 10 mm, 7 mm away).
    pts = np.array([[0.0, 0, 0], [0.01, 0, 0]])
    T_gt = np.eye(4)
    T_est = _pose([0, 0, 0], [0.007, 0, 0])
    assert M.adi(pts, T_est, T_gt) == pytest.approx(0.005)
    # the same relative error at another true pose gives the same ADI
    T_gt2 = _pose([0.3, -1.0, 0.2], [0.5, 0.1, -0.2])
    assert M.adi(pts, T_gt2 @ T_est, T_gt2) == pytest.approx(0.005)


def test_adi_averages_over_the_points_at_the_true_pose():
    # Three points on x at 0, 10 and 11 mm; the estimate is shifted 10 mm along x, to 10, 20, 21 mm.
    # Over the true points (the reference direction): 0 -> 10 is 10 mm, 10 -> 10 is 0, 11 -> 10 is 1:
    # 11/3 mm. Over the estimated points it would be 0, 9 and 10 mm: 19/3 mm.
    pts = np.array([[0.0, 0, 0], [0.010, 0, 0], [0.011, 0, 0]])
    T_est = _pose([0, 0, 0], [0.010, 0, 0])
    assert M.adi(pts, T_est, np.eye(4)) == pytest.approx(0.011 / 3)
    assert M.adi(pts, np.eye(4), T_est) == pytest.approx(0.019 / 3)


def naive_adi(pts, T_est, T_gt):
    """ADI by a double loop in the reference direction: for each point at the true pose, the nearest
    point at the estimated pose."""
    at_gt, at_est = g.transform_points(T_gt, pts), g.transform_points(T_est, pts)
    return np.mean([min(np.linalg.norm(p - q) for q in at_est) for p in at_gt])


def test_adi_matches_a_naive_double_loop_on_an_uneven_point_set():
    rng = np.random.default_rng(5)
    # a dense cluster and a sparse tail: the two directions of ADI disagree on such sets
    pts = np.vstack([rng.normal(size=(40, 3)) * 0.002, rng.normal(size=(12, 3)) * 0.04])
    T_gt = _pose(rng.normal(size=3), [0.1, 0, 0.2])
    T_est = np.stack([_pose(rng.normal(size=3), [0.1, 0, 0.2] + rng.normal(size=3) * 0.01) for _ in range(4)])
    expected = [naive_adi(pts, T, T_gt) for T in T_est]
    np.testing.assert_allclose(M.adi(pts, T_est, T_gt), expected, rtol=1e-12)
    reverse = [naive_adi(pts, T_gt, T) for T in T_est]
    assert np.max(np.abs(np.subtract(expected, reverse))) > 1e-3


def test_adi_is_zero_under_symmetries():
    rng = np.random.default_rng(1)
    # a cube's corners and face centres: a 90-degree turn about z maps the set onto itself
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * 0.03
    cube = np.vstack([corners, np.eye(3) * 0.03, -np.eye(3) * 0.03])
    # a cylinder sampled at 36 angles: any multiple of 10 degrees about z is a symmetry
    ang = np.radians(np.arange(0, 360, 10))
    ring = np.stack([0.04 * np.cos(ang), 0.04 * np.sin(ang), np.zeros_like(ang)], axis=1)
    cylinder = np.vstack([ring + [0, 0, z] for z in np.linspace(-0.05, 0.05, 5)])
    T_gt = _pose(rng.normal(size=3), [0.1, 0, 0.2])
    for pts, angle in ((cube, np.pi / 2), (cylinder, np.radians(30))):
        T_est = T_gt @ _pose([0, 0, angle], [0, 0, 0])
        assert M.adi(pts, T_est, T_gt) < 1e-12
        assert M.positional_error(T_est, T_gt) < 1e-12


def test_adi_batched_matches_single_and_rotation_only_ignores_translation():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(300, 3)) * 0.03
    T_gt = _pose(rng.normal(size=3), rng.normal(size=3) * 0.1)
    T_est = g.make_pose(g.random_rotations(7, rng), rng.normal(size=(7, 3)) * 0.1)
    batched = M.adi(pts, T_est, T_gt, M.model_tree(pts))
    assert batched.shape == (7,)
    np.testing.assert_allclose(batched, [M.adi(pts, T, T_gt) for T in T_est], rtol=1e-12)
    rot = M.adi_rotation_only(pts, T_est, T_gt)
    shifted = T_est.copy()
    shifted[:, :3, 3] += rng.normal(size=(7, 3))
    np.testing.assert_allclose(M.adi_rotation_only(pts, shifted, T_gt), rot, rtol=1e-12)
    # a pure translation error has rotation-only ADI 0
    T_moved = T_gt.copy()
    T_moved[:3, 3] += [0.05, 0, 0]
    assert M.adi_rotation_only(pts, T_moved, T_gt) < 1e-15
    assert M.adi(pts, T_moved, T_gt) > 0.0


def test_auc_by_hand():
    d = [0.005, 0.03, 0.01]
    # paper: finite sorted 0.005, 0.01 (m = 2 of n = 3); (2 - 10 * 0.005) / 3 = 0.65.
    # Directly: 0.005 * 1/3 + 0.005 * 2/3 + (0.1 - 0.01) * 2/3 = 0.065, over 0.1.
    assert M.auc_vocap(d) == pytest.approx(0.65)
    assert M.auc_vocap_closed_form(d) == pytest.approx(0.65)
    assert M.adi_auc(d, "paper") == pytest.approx(0.65)
    # standard: mean of 0.75, 0, 0.5
    assert M.adi_auc(d, "standard") == pytest.approx(1.25 / 3)
    assert M.adi_auc([0.0, 0.0], "paper") == 1.0
    assert M.adi_auc([0.0, 0.0], "standard") == 1.0
    assert M.adi_auc([0.021, 0.5], "paper") == 0.0
    assert M.adi_auc([0.02], "standard") == 0.0
    with pytest.raises(ValueError):
        M.adi_auc(d, "other")
    with pytest.raises(ValueError):
        M.adi_auc([], "paper")


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.one_of(st.floats(0.0, 0.025), st.sampled_from([0.0, 0.01, 0.02, 0.03])), min_size=1, max_size=40
    )
)
def test_vocap_closed_form_equals_direct_integration(d):
    assert M.auc_vocap_closed_form(d) == pytest.approx(M.auc_vocap(d), abs=1e-12)
    assert 0.0 <= M.auc_vocap(d) <= 1.0
    # VOCap credits each finite distance from the previous one on, so it never scores below the
    # exact step-curve area over the same range, mean(1 - d / 0.1) over the finite d
    finite = np.asarray(d)[np.asarray(d) <= 0.02]
    assert M.auc_vocap(d) >= np.sum(1 - finite / 0.1) / len(d) - 1e-12


def test_vocap_on_random_data():
    rng = np.random.default_rng(3)
    for _ in range(50):
        d = rng.exponential(0.015, size=rng.integers(1, 60))
        assert M.auc_vocap_closed_form(d) == pytest.approx(M.auc_vocap(d), abs=1e-12)


def test_top_k_helpers_and_ranked_errors():
    values = np.array([[3.0, 1.0, 2.0, 4.0, 5.0, 100.0], [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]])
    np.testing.assert_allclose(M.best(values), [3.0, 1.0])
    np.testing.assert_allclose(M.mean_top_k(values), [3.0, 1.0])
    np.testing.assert_allclose(M.mean_top_k(values[:, :2]), [2.0, 1.0])
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(100, 3)) * 0.03
    T_gt = _pose([0, 0, 0], [0.1, 0, 0.2])
    T_ranked = np.stack([_pose([0, 0, 0], [0.1 + 0.01 * k, 0, 0.2]) for k in range(8)])
    errs = M.ranked_pose_errors(pts, T_ranked, T_gt)
    np.testing.assert_allclose(errs["position"], 0.01 * np.arange(5), atol=1e-15)
    np.testing.assert_allclose(errs["adi_rotation"], 0.0, atol=1e-15)
    assert errs["adi"][0] == 0.0 and np.all(errs["adi"][1:] > 0)


def test_auroc_against_pairwise_counting():
    rng = np.random.default_rng(0)
    pos, neg = rng.normal(1.0, 1.0, 40), rng.normal(0.0, 1.0, 30)
    pos[:3] = neg[:3]  # some ties
    pairs = (pos[:, None] > neg[None, :]).mean() + 0.5 * (pos[:, None] == neg[None, :]).mean()
    assert M.auroc(pos, neg) == pytest.approx(pairs)
    assert M.auroc([2.0, 3.0], [0.0, 1.0]) == 1.0 and M.auroc([0.0], [1.0]) == 0.0


def test_auroc_within_groups_counts_only_same_group_pairs():
    rng = np.random.default_rng(1)
    pos, neg = rng.normal(1.0, 1.0, 50), rng.normal(0.0, 1.0, 40)
    pos_groups, neg_groups = rng.integers(0, 4, 50), rng.integers(1, 5, 40)  # group 0 and 4 have one side only
    pos[pos_groups == 3] += 10.0  # an offset of one group: only its own pairs see it
    same = pos_groups[:, None] == neg_groups[None, :]
    wins = (pos[:, None] > neg[None, :]) + 0.5 * (pos[:, None] == neg[None, :])
    assert M.auroc_within_groups(pos, neg, pos_groups, neg_groups) == pytest.approx(wins[same].mean())
    # A constant offset between groups, which pooled AUROC punishes, leaves it unchanged:
    shifted_pos, shifted_neg = pos + 5.0 * pos_groups, neg + 5.0 * neg_groups
    assert M.auroc_within_groups(shifted_pos, shifted_neg, pos_groups, neg_groups) == pytest.approx(wins[same].mean())
    assert np.isnan(M.auroc_within_groups([1.0], [0.0], ["a"], ["b"]))
    with pytest.raises(ValueError):
        M.auroc_within_groups([1.0, 2.0], [0.0], ["a"], ["a"])
