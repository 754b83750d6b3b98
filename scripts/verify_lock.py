"""Re-make stages recorded in dvc.lock into a temporary directory and check their outputs byte for byte.

    python scripts/verify_lock.py sample_distractors report
    python scripts/verify_lock.py --ignore-timings 'render_database@*'
    python scripts/verify_lock.py --against ../old-run --ignore-timings     # after a full dvc repro

A stage may be recorded with ``dvc commit -f STAGE`` instead of re-run only when this script has re-made
its outputs with the workspace's code and found them identical to what dvc.lock records
(docs/pipeline.md, "Stages recorded without re-running them"). For each stage named (as dvc.lock spells
it; shell patterns such as ``render_database@*`` select several) it:

1. reads the stage's resolved command, deps, params and outs from dvc.lock;
2. builds a shadow workspace in a temporary directory, at the same relative paths: the code and config
   copied (a snapshot that others editing the tree cannot change under the stage), the pipeline's data
   hard-linked (symlinked across file systems), but of the outputs of the stages only this stage's deps;
   its own outs are absent, as ``dvc repro`` deletes them first. The command runs there unchanged, so
   whatever it writes relative to the repository (``artifacts/``, ``reports/``) lands in the shadow,
   and no ``paths.artifacts_dir`` override changes what a stage stamps into its files;
3. checks the shadow's deps and params against the lock: a changed *code* dep (any dep no stage
   makes: the stages' modules, the library, conf/) is what is being verified and is reported as
   ``code changed``; a changed data dep (another stage's output) or param makes the comparison
   meaningless, so the stage is not run;
4. compares the md5 of every out (DVC's own md5; for a directory, DVC's ``.dir`` hash of its listing)
   with the lock's and prints one line per out. For an out that differs it names what differs: HDF5
   datasets and attributes (how many elements, by how much), JSON keys, text lines, files of a
   directory, using the recorded version from the workspace or the DVC cache when either holds it.

``--ignore-timings`` does not compare datasets, attributes and JSON keys whose names look like timings
(``seconds``, ``seconds_*``, ``*_seconds``, ``ms``, ``*_ms``, ``*_ms_*``, ``time_s*``, ``wall_s``, ``*_s``,
``*_per_s``): an out that differs only there counts as identical, and the line says which names were left out.

``--against OLD`` re-makes nothing: after a full ``dvc repro`` of this workspace, it compares every out that
this workspace's dvc.lock records with what OLD's dvc.lock records for the same stage (OLD: another
checkout of the project that ran the pipeline, its files or its DVC cache holding the recorded versions),
the same way, and prints one line per out that differs and a count of outs by verdict. Stage patterns then
narrow the comparison (default: every stage of this workspace's dvc.yaml).

``--write-digests FILE`` re-makes nothing either: it writes, for every out dvc.lock records, its md5 and a digest
of its content less its timings (``content_digest``), and ``--against-digests FILE`` compares this workspace's
outs with such a file: the same md5, else the same digest ("identical except timings"), else "differs". The
run that writes dvc.lock writes ``reports/output_digests.json`` so (``make reproduce``), and it is committed with
dvc.lock, so that a run on another machine is compared in full without the first run's files:

    python scripts/verify_lock.py --write-digests reports/output_digests.json    # after dvc.lock is written
    python scripts/verify_lock.py --against-digests ../main/reports/output_digests.json   # another run

Exit status: 0 when every out of every stage is identical, 1 when an out differs, 2 when a stage could not
be verified (unknown stage, changed data dep or param, missing dep, the command failed). The last lines
printed are a summary to paste into the commit message that records the stages. Nothing in the workspace
(artifacts/, reports/, dvc.lock) or in the DVC cache is written; ``--keep`` leaves the shadow for a look.
"""

from __future__ import annotations

import argparse
import configparser
import fnmatch
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

# A name (an HDF5 dataset or attribute, a JSON key, or any folder of its path) that holds a duration or
# a rate measured on the clock: these change from one run to the next with the same code.
TIMES_DIR = "artifacts/times"  # each stage's wall-time record: a timing by definition
TIMING_NAME = re.compile(r"(^|_)(seconds|secs|ms|time_s|wall_s|elapsed)(_|$)|_s$|_per_s$", re.IGNORECASE)
MAX_DETAIL_LINES = 12  # per out: enough to see what differs without burying the summary

OK, DIFFERS, UNVERIFIED = 0, 1, 2  # exit statuses, worst wins
MATCHING = ("same md5", "identical except timings")  # the verdicts of a comparison of two runs that pass


# --- reading dvc.lock and params files ----------------------------------------------------------------

def load_yaml(path: Path):
    """A YAML file read as DVC reads it (ruamel, YAML 1.2), so that values compare as DVC compared them."""
    from ruamel.yaml import YAML

    return YAML(typ="safe", pure=True).load(Path(path).read_text())


def lock_stages(root: Path) -> dict[str, dict]:
    """dvc.lock's stages: name -> {cmd, deps, params, outs}."""
    lock = root / "dvc.lock"
    if not lock.is_file():
        raise SystemExit(f"error: no dvc.lock in {root}")
    data = load_yaml(lock) or {}
    return dict(data.get("stages", {}))


def select_stages(stages: dict, patterns: list[str]) -> tuple[list[str], list[str]]:
    """The lock's stage names matching the patterns, in the order given, and the patterns that match none."""
    chosen, unknown = [], []
    for pattern in patterns:
        found = [name for name in stages if fnmatch.fnmatchcase(name, pattern)]
        if not found:
            unknown.append(pattern)
        chosen += [name for name in found if name not in chosen]
    return chosen, unknown


def stage_cmd(entry: dict) -> str:
    """The resolved command; a list of commands runs one after the other, as DVC runs them."""
    cmd = entry["cmd"]
    return " && ".join(cmd) if isinstance(cmd, list) else str(cmd)


def param_value(tree, dotted: str):
    """Value at a dotted key of a params tree; KeyError if absent."""
    node = tree
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(dotted)
        node = node[part]
    return node


def cache_dir(root: Path) -> Path:
    """The DVC cache: ``cache.dir`` of .dvc/config.local or .dvc/config (relative to .dvc/), else .dvc/cache."""
    dvc_dir = root / ".dvc"
    for name in ("config.local", "config"):
        parser = configparser.ConfigParser()
        try:
            parser.read(dvc_dir / name)
        except configparser.Error:
            continue
        if parser.has_option("cache", "dir"):
            return (dvc_dir / os.path.expanduser(parser.get("cache", "dir"))).resolve()
    return dvc_dir / "cache"


# --- md5 as DVC computes it ---------------------------------------------------------------------------

def file_md5(path: Path) -> str:
    """md5 of the bytes (DVC 3's ``hash: md5``)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "md5").hexdigest()


def _files_below(path: Path) -> list[str]:
    """Every file below ``path`` (relpath with /), links followed as DVC follows them, sorted."""
    return sorted((Path(folder) / name).relative_to(path).as_posix()
                  for folder, _, files in os.walk(path, followlinks=True) for name in files)


def dir_listing(path: Path) -> dict[str, str]:
    """relpath (with /) -> md5 of every file below ``path``, links followed, as DVC lists a directory out."""
    return {rel: file_md5(path / rel) for rel in _files_below(path)}


def listing_md5(listing: dict[str, str]) -> str:
    """DVC's hash of a directory: md5 of the JSON of its sorted listing, with ``.dir`` appended."""
    entries = [{"md5": md5, "relpath": rel} for rel, md5 in sorted(listing.items())]
    return hashlib.md5(json.dumps(entries, sort_keys=True).encode("utf-8")).hexdigest() + ".dir"


def path_md5(path: Path) -> str | None:
    """DVC's md5 of a file or directory; None when it does not exist."""
    if path.is_dir():
        return listing_md5(dir_listing(path))
    if path.is_file():
        return file_md5(path)
    return None


def cached_object(cache: Path, md5: str) -> Path | None:
    """The cache's file holding the object of this md5 (DVC 3 layout, then DVC 2's), if it is there."""
    for base in (cache / "files" / "md5", cache):
        candidate = base / md5[:2] / md5[2:]
        if candidate.is_file():
            return candidate
    return None


def recorded_listing(root: Path, cache: Path, rel: str, md5: str) -> dict[str, str] | None:
    """The listing of a directory as the lock records it: from the cache's ``.dir`` object, else from
    the workspace when its directory still hashes to the lock's md5; None when neither has it."""
    obj = cached_object(cache, md5)
    if obj is not None:
        return {e["relpath"]: e["md5"] for e in json.loads(obj.read_text())}
    workspace = root / rel
    if workspace.is_dir():
        listing = dir_listing(workspace)
        if listing_md5(listing) == md5:
            return listing
    return None


def recorded_file(root: Path, cache: Path, rel: str, md5: str) -> Path | None:
    """A file holding the recorded version of a file (workspace if unchanged, else the cache), or None."""
    workspace = root / rel
    if workspace.is_file() and file_md5(workspace) == md5:
        return workspace
    return cached_object(cache, md5)


# --- which paths are data --------------------------------------------------------------------------

def under(rel: str, parents) -> bool:
    """Whether ``rel`` is one of ``parents`` or lies inside one."""
    return any(rel == p or rel.startswith(p + "/") for p in parents)


def above(rel: str, paths) -> bool:
    """Whether some path of ``paths`` lies strictly inside ``rel``."""
    return any(p.startswith(rel + "/") for p in paths)


def generated_paths(stages: dict) -> set[str]:
    """Every out of every stage in the lock: the data the pipeline makes, as opposed to code and config."""
    return {norm(out["path"]) for entry in stages.values() for out in entry.get("outs", [])}


def norm(rel: str) -> str:
    return Path(rel).as_posix().rstrip("/")


# --- checking the deps -----------------------------------------------------------------------------

@dataclass
class StageResult:
    name: str
    status: int = OK
    code_changed: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # why the stage was not verified
    outs: list[OutResult] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass
class OutResult:
    path: str
    identical: bool
    verdict: str  # "identical", "identical except timings", "differs", "missing"
    details: list[str] = field(default_factory=list)
    ignored: set[str] = field(default_factory=set)


def check_deps(base: Path, entry: dict, generated: set[str], result: StageResult) -> None:
    """Record code deps under ``base`` that changed (expected) and data deps that changed or are missing
    (blocking)."""
    for dep in entry.get("deps", []):
        rel = norm(dep["path"])
        current = path_md5(base / rel)
        is_data = under(rel, generated) or above(rel, generated)
        if current is None:
            result.problems.append(f"dep missing: {rel} (`dvc pull` or `dvc repro` it first)")
        elif current == dep.get("md5"):
            continue
        elif is_data:
            result.problems.append(f"data dep changed: {rel} (the lock's outs were made from another version)")
        else:
            result.code_changed.append(rel)


def check_params(base: Path, entry: dict, result: StageResult) -> None:
    """A param (in a params file under ``base``) whose value is not the lock's makes the stage a different
    computation: blocking."""
    for file_name, values in (entry.get("params") or {}).items():
        path = base / file_name
        if not path.is_file():
            result.problems.append(f"params file missing: {file_name}")
            continue
        tree = load_yaml(path) or {}
        for key, recorded in values.items():
            try:
                current = param_value(tree, key)
            except KeyError:
                result.problems.append(f"param {file_name}:{key} absent (recorded {recorded!r})")
                continue
            if current != recorded:
                result.problems.append(f"param changed: {file_name}:{key} ({_short(recorded)} -> {_short(current)})")


def _short(value, limit: int = 60) -> str:
    text = json.dumps(value, default=str, sort_keys=True)
    return text if len(text) <= limit else text[:limit - 3] + "..."


# --- the shadow workspace --------------------------------------------------------------------------

def link_file(src: Path, dst: Path) -> None:
    """Hard link a data file (so that the stage sees it under the shadow's path, as it would in the
    workspace, and a later `dvc checkout` replacing the workspace's file does not change it); a symbolic
    link where the two are on different file systems or the kernel refuses the hard link."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        os.symlink(src.resolve(), dst)


def build_shadow(root: Path, shadow: Path, deps: set[str], outs: set[str], generated: set[str]) -> None:
    """Mirror the workspace into ``shadow``: folders re-created, the pipeline's data hard-linked, code and
    config copied (small; a copy is a snapshot that others editing the tree cannot change while the stage
    runs, and it is what the deps are checked on). Left out: hidden entries (.git, .dvc, .venv),
    __pycache__, this stage's outs, and the outputs of other stages that are not deps of this one (so
    that an undeclared dep fails here instead of being read unnoticed)."""

    def visit(src: Path, rel: str, inside_dep: bool) -> None:
        for child in sorted(os.listdir(src)):
            child_rel = f"{rel}/{child}" if rel else child
            path = src / child
            if not inside_dep and (child.startswith(".") or child == "__pycache__"):
                continue
            if under(child_rel, outs):
                continue
            dep_here = inside_dep or child_rel in deps
            data = under(child_rel, generated)
            if not dep_here and data and not above(child_rel, deps):
                continue
            if path.is_dir():
                (shadow / child_rel).mkdir(parents=True, exist_ok=True)
                visit(path, child_rel, dep_here)
            elif path.is_file() and data:
                link_file(path, shadow / child_rel)
            elif path.is_file():
                shutil.copy2(path, shadow / child_rel)

    shadow.mkdir(parents=True, exist_ok=True)
    visit(root, "", False)


def run_command(cmd: str, shadow: Path, log: Path, stage: str) -> int:
    """Run the stage's command in the shadow as DVC does (a shell, ``$DVC_STAGE`` set to the stage's name,
    which the stage clock reads), with this Python's folder first on PATH, so that ``python`` is the
    interpreter this script runs under (the project's venv)."""
    env = dict(os.environ, DVC_STAGE=stage)
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    with open(log, "w") as out:
        return subprocess.run(cmd, shell=True, cwd=shadow, env=env, stdout=out, stderr=subprocess.STDOUT,
                              check=False).returncode


def stat_snapshot(paths: list[Path]) -> dict[str, tuple]:
    """(size, mtime) of each path and of every file below it: to prove the run left the workspace alone."""
    snap = {}
    for path in paths:
        items = [path] if not path.is_dir() else [p for p in path.rglob("*") if p.is_file()]
        for p in items:
            if p.exists():
                st = p.stat()
                snap[str(p)] = (st.st_size, st.st_mtime_ns)
    return snap


# --- comparing contents -----------------------------------------------------------------------------

def is_timing(name: str) -> bool:
    """Whether a dataset/key path (``a/b`` or ``a.b``) names a timing in any of its parts."""
    return any(TIMING_NAME.search(part) for part in re.split(r"[/.]", name) if part)


def _number_diff(old, new) -> str:
    if isinstance(old, (int, float)) and isinstance(new, (int, float)) and not isinstance(old, bool):
        return f"{old!r} -> {new!r} (diff {new - old:+.3g})"
    return f"{_short(old, 40)} -> {_short(new, 40)}"


def diff_json_values(old, new, prefix: str = "") -> list[tuple[str, str]]:
    """(key path, what changed) for every leaf of two JSON values that differs."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in sorted(set(old) | set(new), key=str):
            path = f"{prefix}.{key}" if prefix else str(key)
            if key not in new:
                out.append((path, "removed"))
            elif key not in old:
                out.append((path, "added"))
            else:
                out += diff_json_values(old[key], new[key], path)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        out = []
        for i, (a, b) in enumerate(zip(old, new)):
            out += diff_json_values(a, b, f"{prefix}[{i}]")
        return out
    same = old == new or (isinstance(old, float) and isinstance(new, float) and old != old and new != new)
    return [] if same else [(prefix or "(top level)", _number_diff(old, new))]


def torch_as_json(path: Path):
    """A PyTorch checkpoint (a dict of tensors, numbers, strings...) as a JSON value: each tensor replaced by
    the sha256 of its bytes, its shape and dtype."""
    import torch

    def plain(value):
        if isinstance(value, torch.Tensor):
            return {"tensor": hashlib.sha256(value.detach().cpu().contiguous().numpy().tobytes()).hexdigest(),
                    "shape": list(value.shape), "dtype": str(value.dtype)}
        if isinstance(value, dict):
            return {str(k): plain(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        return value

    return plain(torch.load(path, map_location="cpu", weights_only=False))


def diff_torch(old: Path, new: Path) -> list[tuple[str, str]]:
    """Named differences of two PyTorch checkpoints: each tensor compared bit for bit, the rest as JSON
    values. The file's bytes differ between two saves of the same weights whenever anything else in it does
    (the training's seconds in the autoencoder's history)."""
    return diff_json_values(torch_as_json(old), torch_as_json(new))


def _strip_index(path: str) -> str:
    return re.sub(r"\[\d+\]", "", path)


def diff_json(old: Path, new: Path) -> list[tuple[str, str]]:
    return diff_json_values(json.loads(Path(old).read_text()), json.loads(Path(new).read_text()))


def _array_diff(a, b) -> str | None:
    """What differs between two arrays, or None if they are equal (NaN equal to NaN)."""
    import numpy as np

    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype != b.dtype:
        return f"shape/dtype {a.shape} {a.dtype} -> {b.shape} {b.dtype}"
    if a.dtype.kind in "fc":
        equal = (a == b) | (np.isnan(a) & np.isnan(b))
    else:
        equal = a == b
    equal = np.asarray(equal)
    if equal.all():
        return None
    n = int((~equal).sum())
    text = f"{n} of {a.size} elements differ"
    if a.dtype.kind in "fciu" and a.dtype.kind != "b":
        with np.errstate(invalid="ignore", over="ignore"):
            delta = np.abs(a.astype(np.complex128 if a.dtype.kind == "c" else np.float64)
                           - b.astype(np.complex128 if b.dtype.kind == "c" else np.float64))
        finite = delta[~equal & np.isfinite(delta)]
        if finite.size:
            text += f", max |diff| {finite.max():.3g}"
    return text


def _hdf5_objects(f) -> tuple[dict, dict]:
    """datasets (path -> array) and attributes ('path@attr' -> value) of an open HDF5 file."""
    import h5py

    datasets, attrs = {}, {}

    def take_attrs(name, obj):
        for key, value in obj.attrs.items():
            attrs[f"{name or '/'}@{key}"] = value

    def visit(name, obj):
        take_attrs(name, obj)
        if isinstance(obj, h5py.Dataset):
            datasets[name] = obj.asstr()[()] if obj.dtype.kind == "O" else obj[()]

    take_attrs("", f)
    f.visititems(visit)
    return datasets, attrs


def _attr_diff(name: str, a, b) -> list[tuple[str, str]]:
    """Attribute differences; JSON-text attributes (tactile6d stamps its config and attrs so) by key."""
    def text(v):
        return v.decode() if isinstance(v, bytes) else v

    a, b = text(a), text(b)
    if isinstance(a, str) and isinstance(b, str):
        try:
            return [(f"{name}:{k}" if k != "(top level)" else name, d)
                    for k, d in diff_json_values(json.loads(a), json.loads(b))]
        except ValueError:
            return [] if a == b else [(name, f"{_short(a, 40)} -> {_short(b, 40)}")]
    found = _array_diff(a, b)
    return [] if found is None else [(name, found)]


def diff_hdf5(old: Path, new: Path) -> list[tuple[str, str]]:
    """(dataset or attribute, what changed) between two HDF5 files."""
    import h5py

    with h5py.File(old, "r") as fa, h5py.File(new, "r") as fb:
        da, aa = _hdf5_objects(fa)
        db, ab = _hdf5_objects(fb)
    out = []
    for name in sorted(set(da) | set(db)):
        if name not in db:
            out.append((f"dataset {name}", "removed"))
        elif name not in da:
            out.append((f"dataset {name}", "added"))
        else:
            found = _array_diff(da[name], db[name])
            if found:
                out.append((f"dataset {name}", found))
    for name in sorted(set(aa) | set(ab)):
        if name not in ab:
            out.append((f"attribute {name}", "removed"))
        elif name not in aa:
            out.append((f"attribute {name}", "added"))
        else:
            out += [(f"attribute {n}", d) for n, d in _attr_diff(name, aa[name], ab[name])]
    return out


def diff_text(old: Path, new: Path) -> list[tuple[str, str]]:
    """The first differing line of two text files."""
    a, b = Path(old).read_text().splitlines(), Path(new).read_text().splitlines()
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return [(f"line {i + 1}", f"{_short(x, 50)} -> {_short(y, 50)}")]
    return [("length", f"{len(a)} -> {len(b)} lines")]


def content_diff(old: Path, new: Path) -> list[tuple[str, str]] | None:
    """Named differences of two versions of a file, by its kind; None when its kind cannot be read so."""
    suffix = new.suffix.lower()
    try:
        if suffix in (".h5", ".hdf5"):
            return diff_hdf5(old, new)
        if suffix == ".json":
            return diff_json(old, new)
        if suffix in (".md", ".txt", ".csv", ".yaml", ".yml"):
            return diff_text(old, new)
        if suffix == ".pt":
            return diff_torch(old, new)
    except (OSError, ValueError, UnicodeDecodeError, RuntimeError) as exc:
        return [("(unreadable)", " ".join(str(exc).split()))]
    return None


def _timing_key(item: str) -> str:
    """The name to test against TIMING_NAME: the dataset/attribute/key path without its kind word."""
    return _strip_index(item.split(" ", 1)[-1].replace("@", "/").replace(":", "/"))


def judge_file(old: Path | None, new: Path, label: str, ignore_timings: bool) -> OutResult:
    """Compare a re-made file whose md5 differs from the recorded one by content."""
    if old is None:
        return OutResult(label, False, "differs",
                         ["the recorded version is neither in the workspace nor in the DVC cache: contents not compared"])
    diffs = content_diff(old, new)
    if diffs is None:
        return OutResult(label, False, "differs", [f"{old.stat().st_size} -> {new.stat().st_size} bytes"])
    ignored = {_timing_key(name) for name, _ in diffs if ignore_timings and is_timing(_timing_key(name))}
    kept = [(name, what) for name, what in diffs if not (ignore_timings and is_timing(_timing_key(name)))]
    if not diffs:
        return OutResult(label, False, "differs", ["same datasets, attributes and keys, different bytes"])
    if not kept:
        return OutResult(label, True, "identical except timings", [], ignored)
    return OutResult(label, False, "differs", [f"{name}: {what}" for name, what in kept], ignored)


def compare_out(root: Path, cache: Path, shadow: Path, out: dict, ignore_timings: bool) -> OutResult:
    """The re-made out against the lock's record: by md5, then, if it differs, by content."""
    rel = norm(out["path"])
    recorded, new_path = out.get("md5", ""), shadow / rel
    made = path_md5(new_path)
    if made is None:
        return OutResult(rel, False, "missing", ["the stage did not write it"])
    if made == recorded:
        return OutResult(rel, True, "identical")
    if ignore_timings and under(rel, (TIMES_DIR,)):
        return OutResult(rel, True, "identical except timings", ["a stage-time record (tactile6d.runtime.stage_clock)"], {rel})
    if not recorded.endswith(".dir"):
        return judge_file(recorded_file(root, cache, rel, recorded), new_path, rel, ignore_timings)
    return compare_dir(root, cache, rel, recorded, new_path, ignore_timings)


def compare_dir(root: Path, cache: Path, rel: str, recorded: str, new_path: Path,
                ignore_timings: bool) -> OutResult:
    """A directory out: files added, removed, or differing (each judged as a file)."""
    if not new_path.is_dir():
        return OutResult(rel, False, "differs", ["a file where the lock records a directory"])
    old = recorded_listing(root, cache, rel, recorded)
    if old is None:
        return OutResult(rel, False, "differs",
                         ["the recorded listing is neither in the workspace nor in the DVC cache: files not compared"])
    new = dir_listing(new_path)
    details, ignored = [], set()
    for name in sorted(set(old) - set(new)):
        details.append(f"{name}: removed")
    for name in sorted(set(new) - set(old)):
        details.append(f"{name}: added")
    identical = not details
    for name in sorted(n for n in set(old) & set(new) if old[n] != new[n]):
        source = recorded_file(root, cache, f"{rel}/{name}", old[name])
        sub = judge_file(source, new_path / name, name, ignore_timings)
        ignored |= sub.ignored
        if not sub.identical:
            identical = False
            details += [f"{name}: {d}" for d in sub.details] or [f"{name}: differs"]
    verdict = ("identical except timings" if ignored else "identical") if identical else "differs"
    return OutResult(rel, identical, verdict, details, ignored)


# --- one stage ---------------------------------------------------------------------------------------

def verify_stage(root: Path, cache: Path, stages: dict, name: str, work: Path, ignore_timings: bool) -> StageResult:
    """Build the stage's shadow under ``work``, check its deps and params there, re-make the stage in it
    and compare its outs with the lock's."""
    entry, result = stages[name], StageResult(name)
    generated = generated_paths(stages)
    outs = {norm(o["path"]) for o in entry.get("outs", [])}
    shadow = work / name.replace("/", "_")
    build_shadow(root, shadow, {norm(d["path"]) for d in entry.get("deps", [])}, outs, generated)
    # Checked in the shadow, not the workspace: what is checked is then exactly what the command reads.
    check_deps(shadow, entry, generated, result)
    check_params(shadow, entry, result)
    if not outs:
        result.problems.append("the lock records no outs")
    if result.problems:
        result.status = UNVERIFIED
        return result
    guarded = [root / rel for rel in outs] + [root / "dvc.lock"]
    before = stat_snapshot(guarded)
    log = work / f"{name.replace('/', '_')}.log"
    print(f"{name}: running `{stage_cmd(entry)}` in {shadow}", file=sys.stderr, flush=True)
    status = run_command(stage_cmd(entry), shadow, log, name)
    if stat_snapshot(guarded) != before:
        # The command reached outside the shadow (an absolute path): its outs in the workspace moved.
        result.problems.append("the command changed the workspace's outs or dvc.lock: it writes outside its "
                               "working directory, which this script cannot verify")
        result.status = UNVERIFIED
        return result
    if status != 0:
        tail = log.read_text().splitlines()[-15:]
        # In the shadow, another stage's output that is not a dep is absent: a stage that reads one fails
        # here, which is a dep missing from dvc.yaml rather than a fault of this script.
        result.problems.append(f"the command failed (exit {status}; a file it reads but does not declare as a "
                               f"dep is absent from the shadow); last lines:\n    " + "\n    ".join(tail))
        result.status = UNVERIFIED
        return result
    for out in entry["outs"]:
        found = compare_out(root, cache, shadow, out, ignore_timings)
        result.outs.append(found)
        if not found.identical:
            result.status = max(result.status, DIFFERS)
    return result


# --- reporting -------------------------------------------------------------------------------------

def print_stage(result: StageResult) -> None:
    """One line per out (and per reason a stage was not verified), details indented below."""
    if result.code_changed:
        print(f"{result.name}: code changed: {', '.join(result.code_changed)}")
    for problem in result.problems:
        print(f"{result.name}: NOT VERIFIED: {problem}")
    for out in result.outs:
        line = f"{result.name}: {out.path}: {out.verdict}"
        if out.ignored:
            line += f" (not compared, timings: {', '.join(sorted(out.ignored))})"
        print(line)
        shown = out.details[:MAX_DETAIL_LINES]
        for detail in shown:
            print(f"    {detail}")
        if len(out.details) > len(shown):
            print(f"    ... and {len(out.details) - len(shown)} more")


def git_head(root: Path) -> str:
    """Short commit of the workspace, '+ uncommitted changes' when its tracked files differ from it."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "a workspace outside git"
    return head + (" + uncommitted changes" if dirty else "")


def summary(results: list[StageResult], unknown: list[str], argv: list[str], root: Path) -> str:
    """The paragraph for the commit message of a ``dvc commit``."""
    lines = [f"verify_lock: `python scripts/verify_lock.py {' '.join(argv)}` on {git_head(root)}:"]
    for r in results:
        changed = f" (code changed: {', '.join(r.code_changed)})" if r.code_changed else " (no code changed)"
        if r.problems:
            lines.append(f"- {r.name}: not verified: {r.problems[0].splitlines()[0]}")
            continue
        ignored = sorted(set().union(*(o.ignored for o in r.outs)))
        same = sum(o.identical for o in r.outs)
        text = f"- {r.name}{changed}: {same} of {len(r.outs)} outs identical"
        if ignored:
            text += f" (timings not compared: {', '.join(ignored)})"
        bad = [o.path for o in r.outs if not o.identical]
        if bad:
            text += f"; differ: {', '.join(bad)}"
        lines.append(text)
    for pattern in unknown:
        lines.append(f"- {pattern}: no such stage in dvc.lock")
    worst = max([r.status for r in results] + ([UNVERIFIED] if unknown else []), default=UNVERIFIED)
    verdict = {OK: "every out re-made identical: the stages may be recorded with dvc commit",
               DIFFERS: "some outs differ: re-run these stages, do not dvc commit them",
               UNVERIFIED: "some stages could not be verified: do not dvc commit them"}[worst]
    lines.append(f"result: {verdict}")
    if worst == OK:
        lines.append("then: dvc commit -f " + " ".join(r.name for r in results))
    return "\n".join(lines)


def compare_runs(root: Path, old_root: Path, patterns: list[str], ignore_timings: bool) -> int:
    """``--against``: every out of ``root``'s lock (its stages matching ``patterns``, those of its dvc.yaml when
    none) against
    ``old_root``'s record of it. Prints the outs that differ and the count by verdict; returns the exit status."""
    stages, old_stages = lock_stages(root), lock_stages(old_root)
    names, unknown = select_stages(stages, patterns or pipeline_stages(root))
    old_cache = cache_dir(old_root)
    counts: dict[str, int] = {}
    only_here = [name for name in names if name not in old_stages]
    for name in names:
        if name in only_here:
            continue
        for out in old_stages[name].get("outs", []):
            result = compare_out(old_root, old_cache, root, out, ignore_timings)
            verdict = "same md5" if result.verdict == "identical" else result.verdict
            counts[verdict] = counts.get(verdict, 0) + 1
            if not result.identical:
                print(f"{name}: {result.path}: {verdict}")
                for line in result.details[:MAX_DETAIL_LINES]:
                    print(f"    {line}")
    for pattern in unknown:
        print(f"{pattern}: no stage of this workspace's dvc.lock matches it")
    n_outs = sum(counts.values())
    print(f"\n{git_head(root)} against {old_root} ({git_head(old_root)}): {len(names) - len(only_here)} stages, "
          f"{n_outs} outs: " + ", ".join(f"{counts[v]} {v}" for v in sorted(counts)))
    if only_here:
        print(f"stages not in {old_root}'s dvc.lock (nothing to compare): {', '.join(only_here)}")
    if unknown:
        return UNVERIFIED
    return OK if all(v in MATCHING for v in counts) else DIFFERS


def pipeline_stages(root: Path) -> list[str]:
    """The stages of ``root``'s dvc.yaml (``dvc stage list``): dvc.lock may keep entries of stages since removed."""
    proc = subprocess.run([sys.executable, "-m", "dvc", "stage", "list", "--name-only"], cwd=root, capture_output=True,
                          text=True, env=dict(os.environ, DVC_NO_ANALYTICS="1"))
    if proc.returncode != 0:
        raise SystemExit(f"error: `dvc stage list` failed in {root}: {proc.stderr.strip()}")
    return proc.stdout.split()


# --- timing-free digests: one run's outputs, to compare another machine's run with ------------------------
#
# ``--against`` needs the other run's files. A digest of each out that leaves its timings out (the names
# ``--ignore-timings`` leaves out) travels without them: the run that writes dvc.lock also writes
# reports/output_digests.json, which is committed with it, and a run anywhere else compares its outs with it.

DIGESTS_FILE = "reports/output_digests.json"


def _json_leaves(value, prefix: str = "") -> list[tuple[str, object]]:
    """(key path, leaf) of a JSON value, named as ``diff_json_values`` names them (``a.b[2].c``)."""
    if isinstance(value, dict) and value:
        return [leaf for key in sorted(value, key=str)
                for leaf in _json_leaves(value[key], f"{prefix}.{key}" if prefix else str(key))]
    if isinstance(value, list) and value:
        return [leaf for i, item in enumerate(value) for leaf in _json_leaves(item, f"{prefix}[{i}]")]
    return [(prefix or "(top level)", value)]


def _hdf5_items(path: Path) -> list[tuple[str, object]]:
    """(name, value) of an HDF5 file's datasets and attributes, named as ``diff_hdf5`` names them; an attribute
    holding JSON text (tactile6d stamps its config so) by key."""
    import h5py

    with h5py.File(path, "r") as f:
        datasets, attrs = _hdf5_objects(f)
    items: list[tuple[str, object]] = [(f"dataset {name}", value) for name, value in datasets.items()]
    for name, value in attrs.items():
        text = value.decode() if isinstance(value, bytes) else value
        try:
            parsed = json.loads(text) if isinstance(text, str) else None
        except ValueError:
            parsed = None
        if parsed is None:
            items.append((f"attribute {name}", text))
        else:
            items += [(f"attribute {name}" if key == "(top level)" else f"attribute {name}:{key}", leaf)
                      for key, leaf in _json_leaves(parsed)]
    return items


def _value_sha256(value) -> str:
    """sha256 of a dataset's, attribute's or key's value: an array by its dtype, shape and bytes (so NaN equals
    NaN and -0.0 differs from 0.0, as the bits do), anything else by its JSON text."""
    import numpy as np

    if isinstance(value, (np.ndarray, np.generic)) and value.dtype.kind not in "OUS":
        array = np.ascontiguousarray(value)
        payload = f"{array.dtype.str}{array.shape}".encode() + array.tobytes()
    else:
        plain = value.tolist() if isinstance(value, (np.ndarray, np.generic)) else value
        payload = json.dumps(plain, sort_keys=True, default=str).encode()
    return hashlib.sha256(payload).hexdigest()


def content_digest(path: Path) -> str:
    """sha256 of a file's or directory's content less its timings: HDF5 datasets and attributes, JSON keys and
    a checkpoint's entries by name, those named like timings (``is_timing``) left out; other kinds (PNG,
    NPZ, text) by their bytes; a directory by its files' digests. Two versions with the same digest are what
    ``--ignore-timings`` calls identical (but for text, which it compares line by line)."""
    if path.is_dir():
        lines = [f"{rel}\t{content_digest(path / rel)}" for rel in _files_below(path)]
        return hashlib.sha256("\n".join(lines).encode()).hexdigest()
    suffix = path.suffix.lower()
    try:
        if suffix in (".h5", ".hdf5"):
            items = _hdf5_items(path)
        elif suffix == ".json":
            items = _json_leaves(json.loads(path.read_text()))
        elif suffix == ".pt":
            items = _json_leaves(torch_as_json(path))
        else:
            items = None
    except (OSError, ValueError, UnicodeDecodeError, RuntimeError):
        items = None  # unreadable as its kind: its bytes say whether it is the same
    if items is None:
        with open(path, "rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    kept = sorted(f"{name}\t{_value_sha256(value)}" for name, value in items if not is_timing(_timing_key(name)))
    return hashlib.sha256("\n".join(kept).encode()).hexdigest()


def _cpu_name() -> str:
    """This machine's CPU as Linux names it, with its family and model (the digests say where they were made)."""
    cpuinfo = Path("/proc/cpuinfo")
    fields: dict[str, str] = {}
    for line in cpuinfo.read_text().splitlines() if cpuinfo.is_file() else []:
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    if "model name" not in fields:
        return "unknown CPU"
    return f"{fields['model name']} (family {fields.get('cpu family', '?')} model {fields.get('model', '?')})"


def write_digests(root: Path, patterns: list[str], target: Path) -> int:
    """``--write-digests``: the md5 and ``content_digest`` of every out of ``root``'s dvc.lock (its stages
    matching ``patterns``, all when none) into the JSON file ``target``; nothing is written when an out in the
    workspace is not the version dvc.lock records. Returns the exit status."""
    stages = lock_stages(root)
    names, unknown = select_stages(stages, patterns or list(stages))
    for pattern in unknown:
        print(f"{pattern}: no stage of dvc.lock matches it")
    outs, problems = {}, []
    for name in names:
        for out in stages[name].get("outs", []):
            rel, path = norm(out["path"]), root / norm(out["path"])
            if path_md5(path) != out.get("md5"):
                problems.append(f"{name}: {rel}: not the version dvc.lock records (`dvc checkout` or `dvc repro` first)")
                continue
            outs[rel] = {"stage": name, "md5": out["md5"], "digest": content_digest(path)}
    for line in problems:
        print(line)
    if problems or unknown:
        print(f"nothing written to {target}")
        return UNVERIFIED
    data = {"about": "timing-free digests of the outputs dvc.lock records (scripts/verify_lock.py --against-digests)",
            "commit": git_head(root), "cpu": _cpu_name(), "outs": outs}
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    print(f"{target}: {len(outs)} outs of {len(names)} stages ({data['commit']}, {data['cpu']})")
    return OK


def compare_digests(root: Path, digests: Path, patterns: list[str]) -> int:
    """``--against-digests``: every out of ``root``'s lock (its stages matching ``patterns``, those of its
    dvc.yaml when none) against the digests another run wrote: the same md5, else the same digest (identical
    except timings; a stage-time record of artifacts/times/ always is, as with ``--ignore-timings``), else it
    differs. Prints the outs that do not match and a count by verdict."""
    reference = json.loads(Path(digests).read_text())
    recorded = reference["outs"]
    stages = lock_stages(root)
    names, unknown = select_stages(stages, patterns or pipeline_stages(root))
    counts: dict[str, int] = {}
    for name in names:
        for out in stages[name].get("outs", []):
            rel = norm(out["path"])
            path, ref = root / rel, recorded.get(rel)
            current = path_md5(path)
            if ref is None:
                verdict = "not in the digests"
            elif current is None:
                verdict = "missing"
            elif current == ref["md5"]:
                verdict = "same md5"
            elif under(rel, (TIMES_DIR,)) or content_digest(path) == ref["digest"]:
                verdict = "identical except timings"  # a stage-time record holds its machine and start too
            else:
                verdict = "differs"
            counts[verdict] = counts.get(verdict, 0) + 1
            if verdict not in MATCHING:
                print(f"{name}: {rel}: {verdict}")
    for pattern in unknown:
        print(f"{pattern}: no stage of this workspace's dvc.lock matches it")
    print(f"\n{git_head(root)} against {digests} ({reference.get('commit')}, {reference.get('cpu')}): "
          f"{len(names)} stages, {sum(counts.values())} outs: " + ", ".join(f"{counts[v]} {v}" for v in sorted(counts)))
    if unknown:
        return UNVERIFIED
    return OK if all(v in MATCHING for v in counts) else DIFFERS


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stages", nargs="*", help="stage names as dvc.lock spells them; shell patterns allowed "
                                                  "(required unless --against, --write-digests or --against-digests)")
    parser.add_argument("--ignore-timings", action="store_true",
                        help="do not compare datasets/attributes/keys named like timings (seconds_*, time_s*, ...)")
    parser.add_argument("--repo", default=".", help="root of the DVC repository (default: the current folder)")
    parser.add_argument("--against", metavar="OLD", default=None,
                        help="re-make nothing: compare this workspace's outs with those OLD's dvc.lock records")
    parser.add_argument("--write-digests", metavar="FILE", default=None,
                        help=f"re-make nothing: write the timing-free digests of the outs dvc.lock records (as {DIGESTS_FILE})")
    parser.add_argument("--against-digests", metavar="FILE", default=None,
                        help="re-make nothing: compare this workspace's outs with the digests another run wrote")
    parser.add_argument("--tmp-dir", default=None, help="where to make the shadow workspaces (default: the system's)")
    parser.add_argument("--keep", action="store_true", help="keep the shadow workspaces and logs, and say where")
    args = parser.parse_args(argv)

    root = Path(args.repo).resolve()
    if args.against is not None:
        return compare_runs(root, Path(args.against).resolve(), args.stages, args.ignore_timings)
    if args.write_digests is not None:
        return write_digests(root, args.stages, Path(args.write_digests).resolve())
    if args.against_digests is not None:
        return compare_digests(root, Path(args.against_digests).resolve(), args.stages)
    if not args.stages:
        parser.error("name the stages to re-make (or give --against OLD, --write-digests or --against-digests FILE)")
    stages = lock_stages(root)
    names, unknown = select_stages(stages, args.stages)
    for pattern in unknown:
        print(f"{pattern}: NOT VERIFIED: no stage of dvc.lock matches it")
    cache = cache_dir(root)
    work = Path(tempfile.mkdtemp(prefix="verify_lock-", dir=args.tmp_dir))
    results = []
    try:
        for name in names:
            result = verify_stage(root, cache, stages, name, work, args.ignore_timings)
            print_stage(result)
            results.append(result)
    finally:
        if args.keep:
            print(f"shadow workspaces and logs kept in {work}", file=sys.stderr)
        else:
            shutil.rmtree(work, ignore_errors=True)
    print("\n--- summary (paste into the commit message) ---")
    print(summary(results, unknown, argv, root))
    return max([r.status for r in results] + ([UNVERIFIED] if unknown else []), default=UNVERIFIED)


if __name__ == "__main__":
    sys.exit(main())
