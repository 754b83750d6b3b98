"""The library as a user installs it: ``pip install .`` into a fresh virtual environment, then an estimate
run from another directory, with no checkout's conf/ on the path."""

import json
import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest
from test_estimate_cli import artifacts, scene  # noqa: F401  (fixtures: prim_box artifacts, a triplet folder)

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh venv with this repository installed (not editable); its dependencies are the test
    environment's, seen through a .pth file, so that nothing is downloaded. -> the venv's bin/."""
    root = tmp_path_factory.mktemp("venv")
    venv.create(root, with_pip=False)
    python = root / "bin" / "python"
    purelib = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    Path(purelib, "test_environment.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet", "--no-deps",
                    "--no-build-isolation", str(REPO)], check=True, capture_output=True, text=True)
    return root / "bin"


def run_elsewhere(bin_dir: Path, cwd: Path, *argv: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run([str(bin_dir / argv[0]), *argv[1:]], cwd=cwd, env=env, capture_output=True, text=True)


def test_the_installed_package_has_its_config_and_not_the_checkouts(installed, tmp_path):
    out = run_elsewhere(installed, tmp_path, "python", "-c",
                        "import tactile6d.core.config as c; print(c.CONF_DIR); "
                        "cfg = c.compose_config(['preset=paper']); print(cfg.rank.refine, cfg.select.contacts)")
    assert out.returncode == 0, out.stderr
    conf_dir, preset = out.stdout.splitlines()
    assert Path(conf_dir).is_relative_to(installed.parent) and not Path(conf_dir).is_relative_to(REPO)
    assert preset == "False landmark"  # the paper's preset, a config group, composes from the installed copy


def test_an_installed_estimate_runs_from_another_directory(installed, tmp_path, artifacts, scene):  # noqa: F811
    out = run_elsewhere(installed, tmp_path, "tactile6d", "estimate", "--object", "prim_box", "--scene", str(scene),
                        "--artifacts", str(artifacts), "--json", "select.method=baseline", "select.N=1000")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.splitlines()[0])
    assert len(result["poses"]) == 5
