"""Stage import_package_meshes: copy the meshes of config section ``own_set`` out of the installed package that
ships them (``own_set.package``, e.g. pybullet_data) into ``artifacts/third_party/<name>.<ext>``.

Their entries in config section ``own`` read these copies: a file inside an installed package has no path
that is the same on every machine (virtual environments differ), while DVC needs one to track the mesh
each ``prepare_own`` stage depends on. Writes the copies and ``artifacts/third_party/sources.json`` (package,
its version, each file's path inside it and md5).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import importlib.util
import shutil
import sys
from pathlib import Path

from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import write_json
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed


def package_dir(package: str) -> Path:
    """The directory of an installed package; ConfigError when it is not installed."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError(f"own_set.package: no installed package {package!r} (pybullet_data comes with pybullet)")
    return Path(list(spec.submodule_search_locations)[0])


def package_version(package: str) -> str | None:
    """The version of the distribution that installs ``package`` (pybullet for pybullet_data), if known."""
    for dist in importlib.metadata.packages_distributions().get(package, []):
        return f"{dist} {importlib.metadata.version(dist)}"
    return None


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    package = str(cfg.own_set.package)
    root = package_dir(package)
    out_dir = layout.third_party_meshes_dir(cfg.paths.artifacts_dir)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    sources = {}
    for name, inner in cfg.own_set.files.items():
        src = root / str(inner)
        if not src.is_file():
            raise ConfigError(f"own_set.files.{name}: {package} has no file {inner} (looked in {root})")
        dst = layout.third_party_mesh_file(cfg.paths.artifacts_dir, str(name), src.suffix)
        shutil.copyfile(src, dst)
        sources[str(name)] = {"file": str(inner), "md5": hashlib.md5(src.read_bytes()).hexdigest(), "copy": dst.name}
        print(f"{name}: {package}/{inner} -> {dst}")
    write_json(out_dir / "sources.json", {"package": package, "version": package_version(package), "files": sources})
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
