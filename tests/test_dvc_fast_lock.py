"""scripts/dvc_fast_lock.py: dvc.lock updated entry by entry writes the bytes DVC's own dumper writes."""

import copy
import os
import pickle
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
    fast_lock._ENTRY_VALUES.clear()
    yield
    fast_lock._ENTRY_TEXTS.clear()
    fast_lock._ENTRY_VALUES.clear()


def committed_lock() -> tuple[str, dict]:
    text = (ROOT / "dvc.lock").read_text(encoding="utf-8")
    return text, parse_yaml(text, "dvc.lock")


@pytest.mark.slow
def test_the_committed_lock_is_written_back_byte_for_byte():
    text, data = committed_lock()
    assert len(data["stages"]) > 50
    assert fast_lock.lock_text(data) == text == fast_lock._dump(data)


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_container_shared_by_two_entries_goes_through_dvcs_dump_with_its_alias():
    _, data = committed_lock()
    names = list(data["stages"])
    shared = {"render": {"noise_std": 7.0}}
    data["stages"][names[0]]["params"] = {"params.yaml": shared}
    data["stages"][names[1]]["params"] = {"params.yaml": shared}
    text = fast_lock.lock_text(data)
    assert text == fast_lock._dump(data) and "&id" in text


@pytest.mark.slow
def test_other_top_level_keys_and_no_stages_go_through_dvcs_dump():
    _, data = committed_lock()
    data["datasets"] = [{"name": "d", "type": "dvc", "url": "x"}]
    assert fast_lock.lock_text(data) == fast_lock._dump(data)
    assert fast_lock.lock_text({"schema": "2.0"}) == fast_lock._dump({"schema": "2.0"})
    assert fast_lock.lock_text({"schema": "2.0", "stages": {}}) == "schema: '2.0'\nstages: {}\n"


class CountingParser:
    """DVC's parse_yaml, counting the texts it is handed."""

    def __init__(self):
        self.texts = []

    def __call__(self, text, path, typ="safe"):
        self.texts.append(text)
        return parse_yaml(text, path, typ=typ)


def same(a, b) -> bool:
    """Equal values of equal types in the same order (pickles compare all three)."""
    return pickle.dumps(a) == pickle.dumps(b)


@pytest.mark.slow
def test_the_committed_lock_reads_as_the_whole_file_reads_entry_by_entry():
    text, data = committed_lock()
    parser = CountingParser()
    first = fast_lock.parse_lock(text, "dvc.lock", parser)
    assert same(first, data)
    assert len(parser.texts) == 1 + len(data["stages"])  # the schema, then each entry alone
    again = fast_lock.parse_lock(text, "dvc.lock", parser)
    assert same(again, data) and len(parser.texts) == 1 + len(data["stages"]) + 1  # only the schema again
    # new objects every time: DVC changes what it reads
    again["stages"][next(iter(data["stages"]))]["cmd"] = "changed"
    assert same(fast_lock.parse_lock(text, "dvc.lock", parser), data)


@pytest.mark.slow
def test_after_a_stage_is_written_only_its_entry_is_parsed_again():
    text, data = committed_lock()
    parser = CountingParser()
    fast_lock.parse_lock(text, "dvc.lock", parser)
    names = list(data["stages"])
    data["stages"][names[7]]["outs"][0]["md5"] = "f" * 32
    data["stages"]["a_new_stage"] = {"cmd": "python -m stages.x", "outs": [{"path": "x", "hash": "md5", "md5": "0" * 32}]}
    del data["stages"][names[2]]
    new_text = fast_lock.lock_text(data)
    before = len(parser.texts)
    assert same(fast_lock.parse_lock(new_text, "dvc.lock", parser), parse_yaml(new_text, "dvc.lock"))
    assert len(parser.texts) - before == 3  # the schema, the changed entry and the new one


@pytest.mark.parametrize("case", ["alias", "flow", "twice", "stages_first", "key_after"])
@pytest.mark.slow
def test_texts_the_entries_cannot_be_read_apart_in_are_read_whole(case):
    _, data = committed_lock()
    names = list(data["stages"])
    if case == "alias":  # an anchor in one entry, its alias in another
        shared = {"render": {"noise_std": 7.0}}
        data["stages"][names[0]]["params"] = {"params.yaml": shared}
        data["stages"][names[1]]["params"] = {"params.yaml": shared}
        text = fast_lock._dump(data)
    elif case == "flow":
        text = "schema: '2.0'\nstages: {a: {cmd: x}, b: {cmd: y}}\n"
    elif case == "twice":  # a stage's entry twice: the whole file's loader decides (it refuses)
        whole = fast_lock._dump(data)
        entry = whole[whole.index("\n  " + names[1]) + 1:whole.index("\n  " + names[2]) + 1]
        text = whole + entry
    elif case == "stages_first":
        text = "stages:\n  a:\n    cmd: x\nschema: '2.0'\n"
    else:
        text = fast_lock._dump(data) + "extra: 1\n"
    parser = CountingParser()
    try:
        expected = parse_yaml(text, "dvc.lock")
    except Exception as error:  # noqa: BLE001 (whatever DVC's own loader raises, the fast read raises too)
        with pytest.raises(type(error)):
            fast_lock.parse_lock(text, "dvc.lock", parser)
        return
    assert same(fast_lock.parse_lock(text, "dvc.lock", parser), expected)
    assert parser.texts[-1] == text  # read whole


def test_another_dvc_version_is_left_alone(monkeypatch, capsys):
    import dvc
    import dvc.dvcfile

    import dvc.utils.strictyaml

    original, original_parse = dvc.dvcfile.modify_yaml, dvc.utils.strictyaml.parse_yaml
    monkeypatch.setattr(dvc, "__version__", "9.9.9")
    assert fast_lock.install() is False
    assert dvc.dvcfile.modify_yaml is original and dvc.utils.strictyaml.parse_yaml is original_parse
    assert "9.9.9" in capsys.readouterr().err


def run_dvc(cwd: Path, *args: str, fast: bool) -> str:
    launcher = [str(ROOT / "scripts" / "dvc_fast_lock.py")] if fast else ["-m", "dvc"]
    env = dict(os.environ, DVC_NO_ANALYTICS="1", GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t", GIT_COMMITTER_NAME="t",
               GIT_COMMITTER_EMAIL="t@t")
    return subprocess.run([sys.executable, *launcher, *args], cwd=cwd, env=env, check=True, capture_output=True,
                          text=True).stdout


@pytest.mark.slow
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
        # read back through the fast read too: DVC finds every stage as it left it, and then a changed one
        assert run_dvc(repo, "repro", fast=fast).count("didn't change") == 4
        (repo / "out_b.txt").write_text("changed")
        out = run_dvc(repo, "repro", fast=fast)  # run again or restored from the run cache, not skipped
        assert "Stage 'make@b' didn't change" not in out and "make@b" in out and out.count("didn't change") == 3
    assert locks[True] == locks[False]
    shutil.rmtree(tmp_path)
