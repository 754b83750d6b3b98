"""Loading the configuration a stage or command runs with.

Two sources give the same tree:
- the Hydra tree in ``conf/``, a checkout's or the copy installed with the package, composed with Hydra's
  compose API (so group overrides such as ``objects=primitives`` work), used when a stage runs alone:
  ``python -m stages.X key=value``;
- a composed ``params.yaml`` (``--params params.yaml``), used under DVC, because ``dvc exp run -S``
  writes its overrides there, not into ``conf/``.
"""

from __future__ import annotations

import functools
from pathlib import Path

import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from tactile6d.core.errors import ConfigError

_PACKAGE = Path(__file__).resolve().parents[1]  # tactile6d/
REPO_ROOT = _PACKAGE.parent


def _conf_dir() -> Path:
    """A checkout's ``conf/``; in an installed package, the copy of it installed as ``tactile6d/conf``."""
    checkout = REPO_ROOT / "conf"
    return checkout if (checkout / "config.yaml").is_file() else _PACKAGE / "conf"


CONF_DIR = _conf_dir()


def compose_config(overrides: list[str] | tuple[str, ...] = (), conf_dir: Path | str = CONF_DIR) -> DictConfig:
    """Compose ``conf/config.yaml`` with Hydra-style overrides (``key=value``, ``group=option``)."""
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException

    conf_dir = Path(conf_dir).resolve()
    if not (conf_dir / "config.yaml").is_file():
        raise ConfigError(f"no config.yaml in {conf_dir}")
    try:
        with initialize_config_dir(config_dir=str(conf_dir), version_base=None):
            cfg = compose(config_name="config", overrides=list(overrides))
    except (HydraException, OmegaConfBaseException) as exc:
        raise ConfigError(f"bad config override in {list(overrides)}: {' '.join(str(exc).split())}") from exc
    OmegaConf.set_struct(cfg, True)
    return cfg


@functools.lru_cache(maxsize=None)
def _default_config() -> DictConfig:
    return compose_config()


def default_section(key: str) -> dict:
    """A plain copy of section ``key`` of the default config (``conf/``, or the installed copy): the
    settings library code uses when its caller gives none, so that every default lives in conf/ only."""
    return section_to_dict(_default_config(), key)


def load_params(params_file: Path | str, overrides: list[str] | tuple[str, ...] = ()) -> DictConfig:
    """Read a composed ``params.yaml`` and apply ``key=value`` overrides to existing keys."""
    path = Path(params_file)
    if not path.is_file():
        raise ConfigError(f"params file {path} not found")
    try:
        cfg = OmegaConf.load(path)
        OmegaConf.set_struct(cfg, True)
        for item in overrides:
            if "=" not in item:
                raise ConfigError(f"override {item!r} is not of the form key=value")
            key, value = item.split("=", 1)
            if OmegaConf.select(cfg, key, throw_on_missing=False, default="__absent__") == "__absent__":
                raise ConfigError(f"override {item!r}: no key {key!r} in {path}")
            # values are YAML scalars or lists, as on a Hydra command line: "7" is an int, "null" is None
            OmegaConf.update(cfg, key, yaml.safe_load(value) if value else value, merge=True)
    except OmegaConfBaseException as exc:
        raise ConfigError(f"bad params file {path}: {' '.join(str(exc).split())}") from exc
    return cfg


def load_config(overrides: list[str] | tuple[str, ...] = (), params_file: Path | str | None = None) -> DictConfig:
    """``load_params`` when a params file is given, else ``compose_config``."""
    if params_file is not None:
        return load_params(params_file, overrides)
    return compose_config(overrides)


def require_key(cfg: DictConfig, key: str):
    """The value at dotted ``key``; a ConfigError naming the key when it is missing."""
    value = OmegaConf.select(cfg, key, throw_on_missing=False, default="__absent__")
    if isinstance(value, str) and value == "__absent__":
        raise ConfigError(f"missing config key {key!r}")
    return value


def config_for_workers(cfg) -> dict:
    """``cfg`` (a DictConfig or mapping) as plain resolved containers for another process: picklable, with
    ``paths.artifacts_dir`` and ``paths.data_dir`` made absolute, since a worker's working directory may be
    another (a Dask worker's)."""
    container = OmegaConf.to_container(OmegaConf.create(cfg), resolve=True)
    paths = container.get("paths", {})
    for key in ("artifacts_dir", "data_dir"):
        if paths.get(key) is not None:
            paths[key] = str(Path(paths[key]).expanduser().resolve())
    return container


def section_to_dict(cfg: DictConfig, key: str) -> dict:
    """A config section as a plain dict (for stamping into artifacts)."""
    return OmegaConf.to_container(require_key(cfg, key), resolve=True)


def composed_params_yaml(conf_dir: Path | str = CONF_DIR) -> str:
    """``conf/`` composed with no overrides, as the YAML text of ``params.yaml``."""
    return OmegaConf.to_yaml(compose_config((), conf_dir), resolve=False)


if __name__ == "__main__":
    # `python -m tactile6d.core.config > params.yaml` refreshes the committed params file after editing conf/.
    print(composed_params_yaml(), end="")
