"""scripts/verify_lock.py: re-making a stage recorded in dvc.lock into a temporary directory.

On a tiny DVC repository made here (two stages, a file, an HDF5 file, a directory and a cache: false
out), then, if the data are there, on the project's own sample_surface@036_wood_block.
"""

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from script_loader import load_script

REPO = Path(__file__).resolve().parent.parent
SCRIPT = REPO / "scripts" / "verify_lock.py"
BIN = os.path.dirname(sys.executable)

verify_lock = load_script("verify_lock")

# Stage 1 writes a list and a "timing"; stage 2 sums it into an HDF5 file, a folder of parts and a
# markdown table. The timings come from FAKE_SECONDS so that a test can move them and nothing else.
MAKE_PY = """\
import json, os, sys
from pathlib import Path
n = int(sys.argv[1])
Path("out").mkdir(exist_ok=True)
data = {"values": list(range(n)), "seconds": float(os.environ.get("FAKE_SECONDS", "1.5"))}
Path("out/data.json").write_text(json.dumps(data, sort_keys=True))
"""

SUMMARIZE_PY = """\
import json, os
from pathlib import Path
import h5py
import numpy as np
values = np.array(json.loads(Path("out/data.json").read_text())["values"], dtype=float)
seconds = float(os.environ.get("FAKE_SECONDS", "1.5"))
total = values.sum()
with h5py.File("out/summary.h5", "w") as f:
    f.attrs["config"] = json.dumps({"n": len(values)})
    f.create_dataset("values", data=values)
    f.create_dataset("total", data=total)
    f.create_dataset("timing/seconds_total", data=seconds)
Path("out/parts").mkdir(exist_ok=True)
for i, chunk in enumerate(np.array_split(values, 2)):
    part = {"sum": float(chunk.sum()), "count": len(chunk), "time_s": seconds / 2}
    Path(f"out/parts/part_{i}.json").write_text(json.dumps(part, sort_keys=True))
Path("out/report.md").write_text(f"| total | {total:.1f} |\\n")
"""

DVC_YAML = """\
stages:
  make:
    cmd: python make.py ${n}
    deps:
      - make.py
    params:
      - n
    outs:
      - out/data.json
  summarize:
    cmd: python summarize.py
    deps:
      - summarize.py
      - out/data.json
    outs:
      - out/summary.h5
      - out/parts
      - out/report.md:
          cache: false
"""


def run(cmd, cwd, env=None, check=True):
    env = dict(os.environ if env is None else env, DVC_NO_ANALYTICS="1", PATH=BIN + os.pathsep + os.environ["PATH"])
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    if check:
        assert proc.returncode == 0, f"{cmd} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc


def verify(repo, *args, env=None):
    """The script on ``repo``: (exit status, stdout)."""
    proc = run([sys.executable, str(SCRIPT), "--repo", str(repo), *args], cwd=repo, env=env, check=False)
    return proc.returncode, proc.stdout + proc.stderr


def tree_digest(root: Path) -> dict[str, str]:
    """md5 of every file below root: to show that verifying writes nothing there."""
    return {str(p.relative_to(root)): hashlib.md5(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and ".dvc/tmp" not in p.as_posix()}


@pytest.fixture(scope="module")
def built_repo(tmp_path_factory):
    """The tiny repository after `dvc repro`: dvc.lock written, outs in the workspace and the cache."""
    if shutil.which("dvc", path=BIN) is None:
        pytest.skip("dvc is not installed beside this Python")
    root = tmp_path_factory.mktemp("tiny") / "repo"
    root.mkdir()
    (root / "make.py").write_text(MAKE_PY)
    (root / "summarize.py").write_text(SUMMARIZE_PY)
    (root / "dvc.yaml").write_text(DVC_YAML)
    (root / "params.yaml").write_text("n: 7\n")
    run(["dvc", "init", "--no-scm", "-q"], root)
    run(["dvc", "repro", "-q"], root)
    assert (root / "dvc.lock").is_file()
    return root


@pytest.fixture
def repo(built_repo, tmp_path):
    """A private copy for one test, which may edit it."""
    copy = tmp_path / "repo"
    shutil.copytree(built_repo, copy, symlinks=True)
    return copy


def test_timing_names():
    for name in ("seconds", "seconds_encode", "timing/seconds_total", "load_seconds", "time_s_median",
                 "ours.time_s_encode_median", "wall_s", "median_s", "images_per_s",
                 "summary.update_ms_median", "update_median_ms", "ms"):
        assert verify_lock.is_timing(name), name
    for name in ("values", "total", "pos_err_cm_top1", "n_poses", "points", "sensors", "spacing/nn_mean_m",
                 "items", "terms", "mse"):
        assert not verify_lock.is_timing(name), name


def test_directory_md5_is_dvcs(tmp_path):
    from dvc_data.hashfile.hash_info import HashInfo
    from dvc_data.hashfile.meta import Meta
    from dvc_data.hashfile.tree import Tree

    (tmp_path / "d" / "sub").mkdir(parents=True)
    (tmp_path / "d" / "a.txt").write_text("a")
    (tmp_path / "d" / "sub" / "b.bin").write_bytes(b"\0\1")
    tree = Tree()
    for rel, md5 in verify_lock.dir_listing(tmp_path / "d").items():
        tree.add(tuple(rel.split("/")), Meta(), HashInfo("md5", md5))
    tree.digest()
    assert verify_lock.path_md5(tmp_path / "d") == tree.hash_info.value


def test_json_differences_are_named():
    found = dict(verify_lock.diff_json_values({"a": {"b": 1.0, "c": [1, 2]}, "d": 1}, {"a": {"b": 1.5, "c": [1, 3]}, "e": 2}))
    assert set(found) == {"a.b", "a.c[1]", "d", "e"}
    assert "+0.5" in found["a.b"] and found["d"] == "removed" and found["e"] == "added"


@pytest.mark.slow
def test_nothing_changed_every_out_identical_and_nothing_written(repo):
    before = tree_digest(repo)
    status, out = verify(repo, "make", "summarize")
    assert status == 0, out
    for path in ("out/data.json", "out/summary.h5", "out/parts", "out/report.md"):
        assert f": {path}: identical" in out
    assert "code changed:" not in out and "make (no code changed): 1 of 1 outs identical" in out
    assert "result: every out re-made identical" in out
    assert "\nthen: dvc commit -f make summarize\n" in out.split("--- summary")[1]
    assert tree_digest(repo) == before  # workspace, dvc.lock and cache untouched
    assert not list(repo.glob("*.tmp*"))


@pytest.mark.slow
def test_code_change_that_keeps_the_output_passes(repo):
    with open(repo / "summarize.py", "a") as f:
        f.write("# a comment: the same outputs\n")
    status, out = verify(repo, "summ*")  # a pattern, as for render_database@*
    assert status == 0, out
    assert "summarize: code changed: summarize.py" in out
    assert "summarize (code changed: summarize.py): 3 of 3 outs identical" in out
    assert "make:" not in out


@pytest.mark.slow
def test_code_change_that_alters_the_output_fails_and_names_it(repo):
    code = (repo / "summarize.py").read_text()
    (repo / "summarize.py").write_text(code.replace("total = values.sum()", "total = values.sum() + 1"))
    (repo / "out" / "summary.h5").unlink()  # the recorded version then comes from the DVC cache
    status, out = verify(repo, "summarize")
    assert status == 1, out
    assert "summarize: out/summary.h5: differs" in out
    assert "dataset total: 1 of 1 elements differ, max |diff| 1" in out
    assert "summarize: out/report.md: differs" in out and "line 1" in out
    assert "summarize: out/parts: identical" in out
    assert "differ: out/report.md, out/summary.h5" in out  # in dvc.lock's order
    assert "result: some outs differ" in out


@pytest.mark.slow
def test_ignore_timings(repo):
    env = dict(os.environ, FAKE_SECONDS="9.25")  # other timings, same code and data
    status, out = verify(repo, "summarize", env=env)
    assert status == 1, out
    assert "dataset timing/seconds_total: 1 of 1 elements differ" in out
    assert "part_0.json: time_s: 0.75 -> 4.625" in out

    status, out = verify(repo, "--ignore-timings", "summarize", "make", env=env)
    assert status == 0, out
    assert "out/summary.h5: identical except timings (not compared, timings: timing/seconds_total)" in out
    assert "out/parts: identical except timings (not compared, timings: time_s)" in out
    assert "out/data.json: identical except timings (not compared, timings: seconds)" in out
    assert "out/report.md: identical\n" in out


@pytest.mark.slow
def test_changed_data_dep_or_param_is_not_verified(repo):
    (repo / "out" / "data.json").write_text('{"values": [1], "seconds": 1.5}')
    status, out = verify(repo, "summarize")
    assert status == 2, out
    assert "summarize: NOT VERIFIED: data dep changed: out/data.json" in out
    assert "out/summary.h5" not in out.split("---")[0]  # not run

    (repo / "params.yaml").write_text("n: 8\n")
    status, out = verify(repo, "make", "nosuch")
    assert status == 2, out
    assert "make: NOT VERIFIED: param changed: params.yaml:n (7 -> 8)" in out
    assert "nosuch: no such stage in dvc.lock" in out


@pytest.mark.slow
def test_project_stage_remade_byte_for_byte(tmp_path, data_dir):
    """sample_surface@036_wood_block in a copy of this checkout, its dep made first (and verified) by
    prepare_object@036_wood_block (the quickest object to prepare, ~5 s), so that nothing is read from or
    written to this checkout's artifacts/."""
    tracked = run(["git", "ls-files"], REPO).stdout.split()
    root = tmp_path / "project"
    for rel in tracked:
        if (REPO / rel).is_file():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / rel, root / rel)
    env = dict(os.environ, TACTILE6D_DATA=str(data_dir))
    # The stage records its own seconds, which no re-run reproduces: compared as timings, i.e. not.
    status, out = verify(root, "--ignore-timings", "prepare_object@036_wood_block", env=env)
    if status != 0 and (": code changed:" in out or "NOT VERIFIED" in out):
        pytest.skip(f"this checkout's code differs from dvc.lock and changes the object:\n{out}")
    assert status == 0, out
    run([sys.executable, "-m", "stages.prepare_object", "--params", "params.yaml", "--object", "036_wood_block"],
        root, env=env)
    status, out = verify(root, "--ignore-timings", "sample_surface@036_wood_block", env=env)
    if status != 0 and (": code changed:" in out or "NOT VERIFIED" in out):
        pytest.skip(f"this checkout's code differs from dvc.lock and changes the surface:\n{out}")
    assert status == 0, out
    assert "sample_surface@036_wood_block: artifacts/surfaces/036_wood_block.h5: identical" in out


def test_torch_checkpoints_compare_by_tensors_and_the_training_seconds_are_timings(tmp_path):
    import torch

    weights = {"w": torch.arange(6.0).reshape(2, 3)}
    old, new, other = tmp_path / "old.pt", tmp_path / "new.pt", tmp_path / "other.pt"
    torch.save({"state_dict": weights, "history": {"train_loss": [1.0, 0.5], "seconds": [3.1, 2.9]}}, old)
    torch.save({"state_dict": weights, "history": {"train_loss": [1.0, 0.5], "seconds": [3.4, 2.7]}}, new)
    torch.save({"state_dict": {"w": weights["w"] + 1e-7}, "history": {"train_loss": [1.0, 0.5], "seconds": [3.1, 2.9]}},
               other)
    assert {name for name, _ in verify_lock.diff_torch(old, new)} == {"history.seconds[0]", "history.seconds[1]"}
    assert verify_lock.judge_file(old, new, "model.pt", ignore_timings=True).identical
    assert not verify_lock.judge_file(old, new, "model.pt", ignore_timings=False).identical
    judged = verify_lock.judge_file(old, other, "model.pt", ignore_timings=True)
    assert not judged.identical and any(d.startswith("state_dict.w.tensor") for d in judged.details)


@pytest.mark.slow
def test_against_another_run_compares_every_out(repo, built_repo):
    """--against OLD after a full re-run: the same code gives the same outs (timings aside); a change is named."""
    env = dict(os.environ, FAKE_SECONDS="9.25")
    run(["dvc", "repro", "-f", "-q"], repo, env=env)
    status, out = verify(repo, "--against", str(built_repo))
    assert status == 1, out  # the timings differ
    status, out = verify(repo, "--against", str(built_repo), "--ignore-timings")
    assert status == 0, out
    # data.json, summary.h5 and parts hold timings; report.md does not
    assert "2 stages, 4 outs: 3 identical except timings, 1 same md5" in out
    code = (repo / "summarize.py").read_text()
    (repo / "summarize.py").write_text(code.replace("total = values.sum()", "total = values.sum() + 1"))
    run(["dvc", "repro", "-q"], repo, env=env)
    status, out = verify(repo, "--against", str(built_repo), "--ignore-timings", "summ*")
    assert status == 1, out
    assert "summarize: out/summary.h5: differs" in out and "dataset total: 1 of 1 elements differ" in out
    assert "1 stages, 3 outs:" in out


def test_content_digest_leaves_out_timings_and_nothing_else(tmp_path):
    """Two HDF5 files, two JSON files and two checkpoints that differ only in what is named like a timing have
    one digest; one bit of data more, or a config key changed, gives another."""
    import h5py
    import numpy as np
    import torch

    def h5(name, seconds, values, config):
        path = tmp_path / name
        with h5py.File(path, "w") as f:
            f.attrs["config"] = json.dumps(config)
            f.attrs["seconds_per_scene"] = seconds
            f.create_dataset("values", data=values)
            f.create_dataset("timing/seconds_total", data=seconds)
            f.create_dataset("names", data=np.array(["a", "b"], dtype=h5py.string_dtype()))
        return path

    values = np.array([0.1, 0.2, np.nan])
    base = h5("base.h5", 1.5, values, {"n": 3, "wall_s": 2.0})
    digest = verify_lock.content_digest(base)
    assert verify_lock.content_digest(h5("later.h5", 9.25, values.copy(), {"n": 3, "wall_s": 7.0})) == digest
    one_bit = values.copy()
    one_bit[0] = np.nextafter(one_bit[0], 1.0)
    assert verify_lock.content_digest(h5("bit.h5", 1.5, one_bit, {"n": 3, "wall_s": 2.0})) != digest
    assert verify_lock.content_digest(h5("config.h5", 1.5, values, {"n": 4, "wall_s": 2.0})) != digest

    def js(name, value):
        (tmp_path / name).write_text(json.dumps(value))
        return tmp_path / name

    first = verify_lock.content_digest(js("a.json", {"mean": 0.5, "per_scene": [{"ms": 3, "ok": True}]}))
    assert verify_lock.content_digest(js("b.json", {"per_scene": [{"ok": True, "ms": 9}], "mean": 0.5})) == first
    assert verify_lock.content_digest(js("c.json", {"mean": 0.5, "per_scene": [{"ms": 3, "ok": False}]})) != first

    weights = {"w": torch.arange(6.0)}
    torch.save({"state_dict": weights, "history": {"seconds": [3.1]}}, tmp_path / "old.pt")
    torch.save({"state_dict": weights, "history": {"seconds": [3.4]}}, tmp_path / "new.pt")
    torch.save({"state_dict": {"w": weights["w"] + 1e-6}, "history": {"seconds": [3.1]}}, tmp_path / "other.pt")
    model = verify_lock.content_digest(tmp_path / "old.pt")
    assert verify_lock.content_digest(tmp_path / "new.pt") == model
    assert verify_lock.content_digest(tmp_path / "other.pt") != model

    (tmp_path / "folder").mkdir()
    shutil.copy(base, tmp_path / "folder" / "x.h5")
    folder = verify_lock.content_digest(tmp_path / "folder")
    shutil.copy(tmp_path / "later.h5", tmp_path / "folder" / "x.h5")
    assert verify_lock.content_digest(tmp_path / "folder") == folder
    (tmp_path / "folder" / "y.txt").write_text("more")
    assert verify_lock.content_digest(tmp_path / "folder") != folder


@pytest.mark.slow
def test_digests_compare_another_run_without_its_files(repo, built_repo, tmp_path):
    """--write-digests on one run, --against-digests on a re-run with other timings: every out matches; a
    changed result is named; nothing is written when the workspace is not what dvc.lock records."""
    digests = tmp_path / "digests.json"
    status, out = verify(built_repo, "--write-digests", str(digests))
    assert status == 0, out
    assert set(json.loads(digests.read_text())["outs"]) == {"out/data.json", "out/summary.h5", "out/parts",
                                                             "out/report.md"}
    env = dict(os.environ, FAKE_SECONDS="9.25")
    run(["dvc", "repro", "-f", "-q"], repo, env=env)
    status, out = verify(repo, "--against-digests", str(digests))
    assert status == 0, out
    assert "2 stages, 4 outs: 3 identical except timings, 1 same md5" in out

    code = (repo / "summarize.py").read_text()
    (repo / "summarize.py").write_text(code.replace("total = values.sum()", "total = values.sum() + 1"))
    run(["dvc", "repro", "-q"], repo, env=env)
    status, out = verify(repo, "--against-digests", str(digests))
    assert status == 1, out
    assert "summarize: out/summary.h5: differs" in out and "summarize: out/report.md: differs" in out

    (repo / "out" / "data.json").write_text("{}")  # no longer what dvc.lock records
    stale = tmp_path / "stale.json"
    status, out = verify(repo, "--write-digests", str(stale))
    assert status == 2 and not stale.exists(), out
    assert "make: out/data.json: not the version dvc.lock records" in out


@pytest.mark.slow
def test_committed_digests_are_those_of_dvc_lock():
    """reports/output_digests.json is written with dvc.lock (make reproduce) and must record the same outs at
    the same md5: after a partial `dvc repro`, refresh it with the command of this message."""
    digests = json.loads((REPO / verify_lock.DIGESTS_FILE).read_text())["outs"]
    lock = verify_lock.lock_stages(REPO)
    recorded = {verify_lock.norm(out["path"]): out["md5"] for entry in lock.values() for out in entry.get("outs", [])}
    stale = sorted(rel for rel in set(recorded) | set(digests) if digests.get(rel, {}).get("md5") != recorded.get(rel))
    assert not stale, (f"{len(stale)} outs of dvc.lock are not recorded as they are in {verify_lock.DIGESTS_FILE} "
                       f"(first: {stale[:3]}); in the checkout whose outputs dvc.lock records, run "
                       f"`python scripts/verify_lock.py --write-digests {verify_lock.DIGESTS_FILE}`")


def test_digests_take_a_stage_time_record_for_a_timing(tmp_path, capsys):
    """A stage-time record (artifacts/times/) names the machine and the start beside its seconds: another
    machine's never matches it, and it counts as identical except timings, as with --ignore-timings."""
    import yaml

    (tmp_path / "artifacts" / "times").mkdir(parents=True)
    record, data = tmp_path / "artifacts" / "times" / "s.json", tmp_path / "out.json"
    record.write_text(json.dumps({"cpu": "Intel(R) Xeon(R) Processor", "started": "2026-11-29", "seconds": 3.0}))
    data.write_text(json.dumps({"total": 21.0, "wall_s": 1.0}))
    outs = [{"path": "artifacts/times/s.json", "md5": verify_lock.file_md5(record)},
            {"path": "out.json", "md5": verify_lock.file_md5(data)}]
    (tmp_path / "dvc.lock").write_text(yaml.safe_dump({"schema": "2.0", "stages": {"s": {"cmd": "x", "outs": outs}}}))
    digests = tmp_path / "digests.json"
    assert verify_lock.write_digests(tmp_path, [], digests) == verify_lock.OK

    record.write_text(json.dumps({"cpu": "AMD EPYC", "started": "2026-12-01", "seconds": 2.0}))
    data.write_text(json.dumps({"total": 21.0, "wall_s": 0.7}))
    assert verify_lock.compare_digests(tmp_path, digests, ["s"]) == verify_lock.OK
    assert "2 outs: 2 identical except timings" in capsys.readouterr().out
    data.write_text(json.dumps({"total": 22.0, "wall_s": 0.7}))
    assert verify_lock.compare_digests(tmp_path, digests, ["s"]) == verify_lock.DIFFERS
    assert "s: out.json: differs" in capsys.readouterr().out
