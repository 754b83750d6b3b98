"""scripts/dvc_fast_lock.py: dvc.lock updated entry by entry writes the bytes DVC's own dumper writes."""

import copy
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from script_loader import load_script

ROOT = Path(__file__).parents[1]
fast_lock = load_script("dvc_fast_lock")

from dvc.utils.serialize._yaml import parse_yaml  # noqa: E402


@pytest.fixture(autouse=True)
def fresh_entry_cache():
    fast_lock._ENTRY_TEXTS.clear()
    yield
    fast_lock._ENTRY_TEXTS.clear()


def committed_lock() -> tuple[str, dict]:
    text = (ROOT / "dvc.lock").read_text(encoding="utf-8")
    return text, parse_yaml(text, "dvc.lock")


def test_the_committed_lock_is_written_back_byte_for_byte():
    text, data = committed_lock()
    assert len(data["stages"]) > 50
    assert fast_lock.lock_text(data) == text == fast_lock._dump(data)


def test_after_each_kind_of_change_the_text_is_dvcs_dump():
    text, data = committed_lock()
    fast_lock.lock_text(data)  # every entry's text kept
    names = list(data["stages"])
    # a stage re-run: one entry replaced by a new object with another output hash and a long command
    entry = copy.deepcopy(data["stages"][names[3]])
    entry["outs"][0]["md5"] = "0" * 32
    entry["cmd"] = entry["cmd"] + " --an-option-long-enough-to-be-folded-by-the-emitter " * 3
    data["stages"][names[3]] = entry
    # a value whose type changes but compares equal (1 == True): pickled apart, so dumped again
    params = data["stages"][names[5]].setdefault("params", {}).setdefault("params.yaml", {})
    params["flag"] = 1
    assert fast_lock.lock_text(data) == fast_lock._dump(data)
    params["flag"] = True
    assert fast_lock.lock_text(data) == fast_lock._dump(data)
    assert "flag: true" in fast_lock.lock_text(data)
    # a new stage, a removed one, floats and None
    data["stages"]["new_stage@x"] = {"cmd": "python -m stages.x", "params": {"params.yaml": {"a": 1e-07, "b": None}},
                                     "outs": [{"path": "artifacts/x.h5", "hash": "md5", "md5": "1" * 32, "size": 3}]}
    del data["stages"][names[0]]
    assert fast_lock.lock_text(data) == fast_lock._dump(data)


def test_a_container_shared_by_two_entries_goes_through_dvcs_dump_with_its_alias():
    _, data = committed_lock()
    names = list(data["stages"])
    shared = {"render": {"noise_std": 7.0}}
    data["stages"][names[0]]["params"] = {"params.yaml": shared}
    data["stages"][names[1]]["params"] = {"params.yaml": shared}
    text = fast_lock.lock_text(data)
    assert text == fast_lock._dump(data) and "&id" in text


def test_other_top_level_keys_and_no_stages_go_through_dvcs_dump():
    _, data = committed_lock()
    data["datasets"] = [{"name": "d", "type": "dvc", "url": "x"}]
    assert fast_lock.lock_text(data) == fast_lock._dump(data)
    assert fast_lock.lock_text({"schema": "2.0"}) == fast_lock._dump({"schema": "2.0"})
    assert fast_lock.lock_text({"schema": "2.0", "stages": {}}) == "schema: '2.0'\nstages: {}\n"


def test_another_dvc_version_is_left_alone(monkeypatch, capsys):
    import dvc
    import dvc.dvcfile

    original = dvc.dvcfile.modify_yaml
    monkeypatch.setattr(dvc, "__version__", "9.9.9")
    assert fast_lock.install() is False
    assert dvc.dvcfile.modify_yaml is original
    assert "9.9.9" in capsys.readouterr().err


def run_dvc(cwd: Path, *args: str, fast: bool) -> None:
    launcher = [str(ROOT / "scripts" / "dvc_fast_lock.py")] if fast else ["-m", "dvc"]
    env = dict(os.environ, DVC_NO_ANALYTICS="1", GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t", GIT_COMMITTER_NAME="t",
               GIT_COMMITTER_EMAIL="t@t")
    subprocess.run([sys.executable, *launcher, *args], cwd=cwd, env=env, check=True, capture_output=True)


def test_a_pipeline_run_through_it_writes_the_lock_plain_dvc_writes(tmp_path):
    dvc_yaml = """stages:
  make:
    foreach: [a, b, c]
    do:
      cmd: python -c "open('out_${item}.txt', 'w').write(str(${params.n}) + '${item}')"
      params:
        - params.n
      outs:
        - out_${item}.txt
  join:
    cmd: python -c "open('all.txt', 'w').write(''.join(open('out_' + c + '.txt').read() for c in 'abc'))"
    deps:
      - out_a.txt
      - out_b.txt
      - out_c.txt
    outs:
      - all.txt
"""
    locks = {}
    for fast in (False, True):
        repo = tmp_path / ("fast" if fast else "plain")
        repo.mkdir()
        (repo / "dvc.yaml").write_text(dvc_yaml)
        (repo / "params.yaml").write_text("params:\n  n: 1\n")
        subprocess.run(["git", "init", "-q"], cwd=repo, check=True)
        run_dvc(repo, "init", "-q", fast=fast)
        run_dvc(repo, "repro", fast=fast)
        (repo / "params.yaml").write_text("params:\n  n: 2\n")  # every stage again: the lock rewritten in place
        run_dvc(repo, "repro", fast=fast)
        locks[fast] = (repo / "dvc.lock").read_text()
        assert (repo / "all.txt").read_text() == "2a2b2c"
    assert locks[True] == locks[False]
    shutil.rmtree(tmp_path)
