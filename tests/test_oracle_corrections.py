"""scripts/oracle_corrections.py: the truth scored through the sensors' true errors, on the synthetic world of
tests/test_estimator.py (the score's terms: tactile6d.estimation.rank, tests/test_contacts.py)."""

import numpy as np
import pytest
from test_contacts import lifted_contacts
from test_estimator import T_TRUE, make_estimator, world  # noqa: F401 (world: a fixture)

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from script_loader import load_script

oracle = load_script("oracle_corrections")


@pytest.mark.slow
def test_without_sensor_errors_the_oracle_pays_no_corrections_and_its_terms_add_up(world):
    e = make_estimator(world, **{"rank.refine": "true"})
    T, c = lifted_contacts(world, 1, 0.10)
    scored = oracle.oracle_score(e, T_TRUE, T, T, c)
    terms = oracle.score_terms(scored, e.settings.rank, e.settings.sensors)
    assert terms.shape == (1, 4)
    np.testing.assert_allclose(terms.sum(axis=1), scored.scores, atol=1e-15)
    assert abs(terms[0, 2]) < 1e-12  # no correction, no cost
    assert terms[0, 0] < 1e-4  # the landmarks lie on the cut box


def test_a_sensor_error_the_oracle_knows_is_paid_for_as_its_squared_mahalanobis_norm(world):
    e = make_estimator(world, **{"rank.refine": "true"})
    T, c = lifted_contacts(world, 1, 0.10)
    # Sensor 0 reported 1 sigma (1.5 mm) off along its own y axis: its contact point shifts 1.5 mm, which the
    # corrections' prior (contact sigma 1.6 mm, the lever arm's share included) charges about (1.5 / 1.6)^2,
    # averaged over the two touching sensors.
    reported = T.copy()
    reported[0] = T[0] @ make_pose(rotvec_to_rotmat(np.zeros(3)), [0.0, 0.0015, 0.0])
    terms = oracle.score_terms(oracle.oracle_score(e, T_TRUE, reported, T, c), e.settings.rank, e.settings.sensors)
    sigma = e.settings.sensors.correction_sigmas[0]
    expected = e.settings.rank.pose_correction_weight * (0.0015 / sigma) ** 2 / 2
    assert terms[0, 2] == pytest.approx(expected, rel=1e-6)


def test_exact_sensor_poses_have_no_corrections_to_score(world):
    e = make_estimator(world, **{"rank.refine": "true", "sensors.pose_sigma_mm": 0.0, "sensors.pose_sigma_deg": 0.0})
    T, c = lifted_contacts(world, 1, 0.10)
    with pytest.raises(SystemExit, match="pose_sigma"):
        oracle.oracle_score(e, T_TRUE, T, T, c)
