import pytest
import yaml
from omegaconf import OmegaConf

from tactile6d.core.config import REPO_ROOT, compose_config, load_params, require_key
from tactile6d.core.errors import ConfigError


def test_committed_params_yaml_is_the_composed_config():
    """plain `dvc repro` reads params.yaml: it must not drift from conf/ (refresh: `make params`)."""
    committed = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    assert committed == OmegaConf.to_container(compose_config(), resolve=False)


def test_group_and_key_overrides():
    cfg = compose_config(["objects=primitives", "sample.M=50"])
    assert next(iter(cfg.objects.names)) == "prim_box"
    assert cfg.sample.M == 50


@pytest.mark.slow
def test_unknown_key_is_a_config_error():
    with pytest.raises(ConfigError, match="sample.nope"):
        compose_config(["sample.nope=1"])
    with pytest.raises(ConfigError, match="missing config key 'sample.nope'"):
        require_key(compose_config(), "sample.nope")


def test_params_file_overrides(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text((REPO_ROOT / "params.yaml").read_text())
    cfg = load_params(path, ["sample.M=7", "paths.artifacts_dir=/tmp/x"])
    assert cfg.sample.M == 7 and cfg.paths.artifacts_dir == "/tmp/x"
    with pytest.raises(ConfigError, match="no key 'sample.nope'"):
        load_params(path, ["sample.nope=3"])
    with pytest.raises(ConfigError, match="not found"):
        load_params(tmp_path / "absent.yaml")


@pytest.mark.slow
def test_the_paper_preset_trains_the_autoencoder_on_reconstruction_alone():
    assert compose_config().ae.rank_weight > 0
    assert compose_config(["preset=paper"]).ae.rank_weight == 0
    assert compose_config(["ae=paper"]).ae.rank_weight == 0


def test_every_config_group_is_packaged():
    """An installed tactile6d composes from its own copy of conf/ (tests/test_installed.py): a config group
    missing from pyproject's package list would be left out of the wheel, or make setuptools warn."""
    import tomllib

    setuptools = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    groups = {p.name for p in (REPO_ROOT / "conf").iterdir() if p.is_dir() and any(p.glob("*.yaml"))}
    packaged = {name.removeprefix("tactile6d.conf.") for name in setuptools["packages"]
                if name.startswith("tactile6d.conf.")}
    assert packaged == groups
    assert setuptools["package-dir"]["tactile6d.conf"] == "conf"
    assert "*.yaml" in setuptools["package-data"]["*"]
