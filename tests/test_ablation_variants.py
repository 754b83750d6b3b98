"""Ablation variants (tactile6d.evaluation.ablation_variants) on the real composed config."""

import pytest
from omegaconf import OmegaConf

from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError
from tactile6d.evaluation.ablation_variants import estimator_settings_key, variant_config


@pytest.fixture(scope="module")
def cfg():
    return compose_config()


def test_a_variant_overrides_only_the_estimator_sections(cfg):
    merged = variant_config(cfg, "x", cfg.ablation.variants["paper"])
    assert merged.select.delta_d_rule == "paper" and merged.optimize.solver == "gd"  # the preset's own solver
    fast = variant_config(cfg, "x", cfg.ablation.variants["+best_n"])
    assert fast.optimize.solver == cfg.ablation.solver
    assert merged.render == cfg.render and merged.ae == cfg.ae  # a preset's ae section is not applied
    with pytest.raises(ConfigError, match="may set only preset, select, optimize, rank"):
        variant_config(cfg, "x", OmegaConf.create({"render": {"width": 1}}))


def test_the_paper_variant_is_the_paper_preset_and_paper_fast_differs_by_the_solver_alone(cfg):
    paper = compose_config(["preset=paper"])
    variant = variant_config(cfg, "paper", cfg.ablation.variants["paper"])
    for section in ("select", "optimize", "rank"):
        assert dict(variant[section]) == dict(paper[section]), section
    fast = variant_config(cfg, "paper_fast", cfg.ablation.variants["paper_fast"])
    assert fast.optimize.solver == "fast"
    fast.optimize.solver = "gd"
    assert estimator_settings_key(fast) == estimator_settings_key(variant)


def test_an_unknown_preset_is_named_with_the_known_ones(cfg):
    with pytest.raises(ConfigError, match=r"no preset 'papr'.*\['default', 'paper'\]"):
        variant_config(cfg, "x", {"preset": "papr"})


def test_equal_settings_give_equal_keys_and_any_change_a_new_one(cfg):
    default = variant_config(cfg, "default", {})
    assert estimator_settings_key(default) == estimator_settings_key(variant_config(cfg, "again", None))
    moved = variant_config(cfg, "moved", {"select": {"delta_h": float(cfg.select.delta_h) / 2}})
    assert estimator_settings_key(moved) != estimator_settings_key(default)


def test_normal_settings_that_apply_at_none_of_the_counts_leave_the_key(cfg):
    # +refine, +normal_select and +normal_loss differ only in the normal check and term, which apply up to
    # normal_max_sensors (2) sensors: at L = 3 they are one estimate, with curves over 1..3 three.
    steps = [variant_config(cfg, n, cfg.ablation.variants[n]) for n in ("+refine", "+normal_select", "+normal_loss")]
    assert steps[0].select.normal_tol_deg is None and steps[1].select.normal_tol_deg == 45.0
    assert steps[1].optimize.normal_weight == 0.0 and steps[2].optimize.normal_weight > 0
    assert len({estimator_settings_key(c, (3,)) for c in steps}) == 1
    assert len({estimator_settings_key(c, (1, 2, 3)) for c in steps}) == 3
    assert len({estimator_settings_key(c, (2,)) for c in steps}) == 3
    # the counts are part of the key; a check that applies at any L keeps its settings in it
    assert estimator_settings_key(steps[0], (3,)) != estimator_settings_key(steps[0], (1, 2, 3))
    every_l = variant_config(cfg, "normals_every_L", cfg.ablation.variants["normals_every_L"])
    assert estimator_settings_key(every_l, (3,)) != estimator_settings_key(steps[2], (3,))
