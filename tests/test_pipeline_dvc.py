"""The DVC pipeline on a built-in object, in a throw-away copy of the repository.

Checks what users rely on: `dvc exp run -S sample.M=...` re-runs the sampling stage and nothing
before it, and setting the value back restores the earlier result from the run cache.
"""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def run(cmd, cwd, env):
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, f"{cmd} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout + proc.stderr


@pytest.fixture(scope="module")
def repo_copy(tmp_path_factory):
    if shutil.which("dvc", path=os.path.dirname(os.sys.executable)) is None:
        pytest.skip("dvc is not installed beside this Python")
    root = tmp_path_factory.mktemp("pipeline") / "repo"
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True, check=True).stdout.split()
    for rel in tracked:
        if (REPO / rel).is_file():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / rel, root / rel)
    env = dict(os.environ, DVC_NO_ANALYTICS="1", PATH=os.path.dirname(os.sys.executable) + os.pathsep + os.environ["PATH"],
               GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t", GIT_COMMITTER_NAME="t", GIT_COMMITTER_EMAIL="t@t")
    for cmd in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "copy"]):
        run(cmd, root, env)
    return root, env


def exp_run(root, env, *overrides):
    # only the per-object foundation stages: the rest of the DAG is exercised by its own tests
    args = ["dvc", "exp", "run", "sample_surface", "-S", "objects.names=[prim_box]", "-S", "prepare.collision=hull"]
    for o in overrides:
        args += ["-S", o]
    return run(args, root, env)


@pytest.mark.slow
def test_changing_M_reruns_only_sampling_and_changing_back_uses_the_run_cache(repo_copy):
    root, env = repo_copy
    first = exp_run(root, env, "sample.M=300")
    assert "Running stage 'prepare_object@prim_box'" in first
    assert "Running stage 'sample_surface@prim_box'" in first
    surface = root / "artifacts/surfaces/prim_box.h5"
    original = surface.read_bytes()

    second = exp_run(root, env, "sample.M=200")
    assert "Running stage 'prepare_object@prim_box'" not in second
    assert "Running stage 'sample_surface@prim_box'" in second

    third = exp_run(root, env, "sample.M=300")
    assert "Running stage" not in third
    assert "sample_surface@prim_box' is cached" in third
    assert surface.read_bytes() == original
