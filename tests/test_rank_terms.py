"""scripts/rank_terms.py: the recorded calls become weighted score terms, and the rank module is left as it was."""


import numpy as np
from omegaconf import OmegaConf

import tactile6d.estimation.rank as rank_module
from script_loader import load_script

rank_terms = load_script("rank_terms")


def test_the_terms_are_weighted_as_rank_scores_them():
    rank_cfg = OmegaConf.create({"pose_correction_weight": 2.0, "agreement_weight": 0.5})
    last = {"surface": (np.array([1e-3, 2e-3]), np.array([0.1, 0.0])),
            "penetration": [np.array([9.0, 9.0]), np.array([0.0, 4e-4])],  # the last call: the refined candidates
            "correction": np.array([1e-4, 0.0]), "agreement": np.array([0.0, 2e-3])}
    terms = rank_terms.scene_terms(last, rank_cfg, normal_weight=0.01)
    np.testing.assert_allclose(terms["surface"], [2e-3, 2e-3])
    np.testing.assert_allclose(terms["penetration"], [0.0, 4e-4])
    np.testing.assert_allclose(terms["correction"], [2e-4, 0.0])
    np.testing.assert_allclose(terms["agreement"], [0.0, 1e-3])


def test_the_recorder_puts_the_rank_functions_back():
    before = (rank_module.penetration_cost, rank_module.agreement_cost, rank_module.distinct_in_order,
              rank_module.refinement.sensor_corrections_cost, rank_module.refinement.surface_losses)
    with rank_terms.Recorder() as recorder:
        assert rank_module.penetration_cost is not before[0]
        out = rank_module.penetration_cost(np.array([[1e-3, 3e-3]]), 1e-3)
        np.testing.assert_allclose(out, [2e-3])
        np.testing.assert_allclose(recorder.last["penetration"][-1], [2e-3])
    after = (rank_module.penetration_cost, rank_module.agreement_cost, rank_module.distinct_in_order,
             rank_module.refinement.sensor_corrections_cost, rank_module.refinement.surface_losses)
    assert after == before


def test_favoured_summarises_the_differences_per_term():
    diffs = [{"surface": -1.0, "penetration": 0.0, "correction": 0.5, "agreement": -2.0},
             {"surface": -3.0, "penetration": 0.0, "correction": -0.5, "agreement": 1.0},
             {"surface": 1.0, "penetration": 0.0, "correction": -0.5, "agreement": -5.0}]
    text = rank_terms.favoured(diffs)
    assert "surface -1.00 (median -1.00, 2 scenes)" in text
    assert "penetration +0.00 (median +0.00, 0 scenes)" in text
    assert "correction -0.17 (median -0.50, 2 scenes)" in text
    assert "agreement -2.00 (median -2.00, 2 scenes)" in text
