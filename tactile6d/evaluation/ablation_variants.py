"""Ablation variants: named departures from the composed config, each a set of estimator settings.

A variant (an entry of config section ``ablation.variants``) is a mapping with any of

- ``preset``: the name of a file in ``conf/preset/``, whose ``select``, ``optimize`` and ``rank``
  sections are taken as they are, so that a variant called after a preset is that preset's estimation
  and not a copy of it. A preset's other sections (``ae``: which autoencoder to train) are not applied:
  every variant reads the same encoded databases, made with the pipeline's autoencoder;
- ``select``, ``optimize``, ``rank``: keys merged over those sections, after the preset.

Every variant runs method ``ours`` with the ablation's solver (``ablation.solver``) unless it sets its own.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from tactile6d.core.config import CONF_DIR
from tactile6d.core.errors import ConfigError
from tactile6d.core.settings import OptimizeSettings, SelectSettings

SECTIONS = ("select", "optimize", "rank")


def preset_sections(name: str, conf_dir: Path | str = CONF_DIR) -> dict:
    """The ``select``, ``optimize`` and ``rank`` sections of ``conf/preset/<name>.yaml`` (empty where it has none)."""
    path = Path(conf_dir) / "preset" / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in path.parent.glob("*.yaml"))
        raise ConfigError(f"no preset {name!r} in {path.parent} (there are {known})")
    preset = OmegaConf.to_container(OmegaConf.load(path), resolve=True) or {}
    return {s: preset[s] for s in SECTIONS if s in preset}


def variant_config(cfg: DictConfig, name: str, variant: Mapping | None, conf_dir: Path | str = CONF_DIR) -> DictConfig:
    """The composed config ``cfg`` with variant ``name`` applied (see the module docstring)."""
    variant = OmegaConf.to_container(variant) if isinstance(variant, DictConfig) else dict(variant or {})
    unknown = sorted(set(variant) - {"preset", *SECTIONS})
    if unknown:
        raise ConfigError(f"ablation.variants.{name} may set only preset, {', '.join(SECTIONS)}, not {unknown}")
    base = {"select": {"method": "ours"}, "optimize": {"solver": str(cfg.ablation.solver)}}
    preset = preset_sections(str(variant["preset"]), conf_dir) if variant.get("preset") else {}
    return OmegaConf.merge(cfg, base, preset, {s: variant[s] for s in SECTIONS if s in variant})


def estimator_settings_key(cfg: DictConfig, counts: Sequence[int] | None = None) -> str:
    """The sections an estimate depends on, as canonical JSON: equal keys give equal estimates.

    counts: the sensor counts the estimates are made at (None: any). Then the key holds them, and leaves out
    the normal settings that apply at none of them (``select.normals_apply``, ``optimize.normal_weight_for``:
    the normal check and the normal term are off above ``normal_max_sensors``), so that variants that differ
    only there (``+refine``, ``+normal_select``, ``+normal_loss`` at L = 3) are estimated once.
    """
    sections = {s: OmegaConf.to_container(cfg[s], resolve=True) for s in SECTIONS}
    if counts is None:
        return json.dumps(sections, sort_keys=True)
    select, optimize = SelectSettings.from_cfg(cfg.select), OptimizeSettings.from_cfg(cfg.optimize)
    if not any(select.normals_apply(L) for L in counts):
        sections["select"].update(normal_tol_deg=None, normal_max_sensors=None)
    if not any(optimize.normal_weight_for(L) > 0 for L in counts):
        sections["optimize"].update(normal_weight=0.0, normal_max_sensors=None)
    return json.dumps({"counts": sorted(counts), **sections}, sort_keys=True)
