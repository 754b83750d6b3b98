"""`python -m dvc` with a faster update of dvc.lock: what `make reproduce` runs DVC through.

    python scripts/dvc_fast_lock.py repro [options]      # any dvc command line, as `python -m dvc`

DVC 3.67 updates dvc.lock after every stage it runs by parsing the whole file with ruamel.yaml's
round-trip loader (pure Python, so that comments survive) and writing the whole file back with ruamel's
pure-Python emitter: 3.4 s per stage at this pipeline's lock of 509 KB on the 2-core machine (2.1 s
reading, 1.3 s writing), over 5 minutes of a full run's 102 stages (docs/reproducibility.md). The lock
has no comments to keep: DVC writes it alone. Here, for dvc.lock only, the update

- reads the file with DVC's own safe loader, whose values are those the round-trip loader gives (both YAML
  1.2), one stage's entry at a time (``parse_lock``): an entry's text parsed before gives its value again
  (kept pickled, a fresh copy each time), so only the entry the last stage changed is parsed. The whole file
  through the safe loader took 0.6 s at 122 stages on the 2-core AMD EPYC Zen 3, once before each stage's
  update; DVC's own reads of dvc.lock (collecting the stages) go through the same cache;
- writes it with DVC's own dumper, one top-level key and one stage's entry at a time, and keeps each
  entry's text: the block style puts every entry's text apart from its neighbours', so the file is the
  concatenation of the texts, and only the entry that changed is dumped again (10 ms).

The bytes written are those DVC would write (tests/test_dvc_fast_lock.py compares them with DVC's own
dump on the committed dvc.lock and on the cases where the concatenation could differ). Where it could,
the whole file goes through DVC's dumper as before: a container object shared by two entries (the
emitter would write an anchor and an alias across them), a top-level key other than ``schema`` and
``stages``, no stages. Every other file DVC modifies goes through DVC's own code, and so does everything
under a DVC version other than the one this was checked with (``CHECKED_DVC``), with a note on stderr.
"""

from __future__ import annotations

import io
import os
import pickle
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

CHECKED_DVC = "3.67.1"  # the version pinned in pyproject.toml, whose dvcfile.py and serialize/_yaml.py this follows
LOCK_NAME = "dvc.lock"

# stage name -> (the entry's pickle, its text under ``stages:``): entries DVC left unchanged are not dumped again.
_ENTRY_TEXTS: dict[str, tuple[bytes, str]] = {}
# an entry's text under ``stages:`` -> the pickle of {name: entry} the safe loader gives for it: read once.
_ENTRY_VALUES: dict[str, bytes] = {}


def _dump(data: Any) -> str:
    """DVC's own YAML text of ``data`` (``dvc.utils.serialize._yaml._dump``, ruamel round-trip emitter)."""
    from dvc.utils.serialize._yaml import _dump as dvc_dump

    stream = io.StringIO()
    dvc_dump(data, stream)
    return stream.getvalue()


def _containers(value: Any) -> Iterator[int]:
    """The ids of every dict and list in ``value``, itself included."""
    if isinstance(value, dict):
        yield id(value)
        for v in value.values():
            yield from _containers(v)
    elif isinstance(value, list):
        yield id(value)
        for v in value:
            yield from _containers(v)


def _shares_containers(entries: dict) -> bool:
    """Whether two of the entries hold the same dict or list object (DVC's emitter would write an alias
    from one entry to the other, which no entry's own text has)."""
    seen: set[int] = set()
    for entry in entries.values():
        ids = set(_containers(entry))
        if ids & seen:
            return True
        seen |= ids
    return False


def _entry_text(name: str, entry: Any) -> str:
    """The text of stage ``name``'s entry as it stands under ``stages:`` in DVC's dump (kept while the entry
    pickles the same: equal pickles, equal values of equal types, the same text)."""
    key = pickle.dumps(entry, protocol=5)
    cached = _ENTRY_TEXTS.get(name)
    if cached is not None and cached[0] == key:
        return cached[1]
    text = _dump({"stages": {name: entry}})
    if not text.startswith("stages:\n"):
        raise AssertionError(f"unexpected dump of stage {name!r}: {text[:80]!r}")
    _ENTRY_TEXTS[name] = (key, text[len("stages:\n"):])
    return _ENTRY_TEXTS[name][1]


def lock_text(data: dict) -> str:
    """dvc.lock's text for ``data`` ({'schema': ..., 'stages': {name: entry}}), the bytes DVC's dumper writes."""
    stages = data.get("stages")
    if (set(data) - {"schema", "stages"} or not isinstance(stages, dict) or not stages
            or _shares_containers(stages)):
        return _dump(data)
    parts = []
    for key, value in data.items():
        if key == "stages":
            parts.append("stages:\n")
            parts.extend(_entry_text(name, entry) for name, entry in stages.items())
        else:
            parts.append(_dump({key: value}))
    return "".join(parts)


def _lock_parts(text: str) -> tuple[str, list[str]] | None:
    """dvc.lock's text -> (the text of its other top-level keys, each stage entry's text under ``stages:``),
    or None where the text is not laid out as DVC's dumper lays it out (then it is parsed whole).

    The dumper writes block style, two spaces a level: ``stages:`` on a line of its own, each entry starting
    with its name at two spaces, everything inside it deeper. The other top-level keys (``schema``) come first.
    """
    head, marker, body = text.partition("\nstages:\n")
    if not marker or not head or head[0].isspace():
        return None
    entries: list[str] = []
    for line in body.splitlines(keepends=True):
        if line.startswith("  ") and not line.startswith("   "):
            entries.append(line)  # an entry's name
        elif entries and (line.startswith("    ") or not line.strip()):
            entries[-1] += line
        else:
            return None  # a top-level key after the stages, or something the dumper does not write
    return head + "\n", entries


def parse_lock(text: str, path, parse_yaml) -> Any:
    """What ``parse_yaml(text, path)`` gives for dvc.lock's text (DVC's safe loader), each entry parsed once.

    An entry is parsed alone as ``stages:`` followed by its text, which gives the value the whole file gives it:
    block mappings carry nothing from one entry to the next but anchors, so the whole file is parsed instead
    where an entry's text holds ``&`` or ``*`` at all, where an entry does not parse to one stage, or where a
    name comes twice. Values come out of pickles, new objects on every call: DVC changes what it reads.
    """
    parts = _lock_parts(text)
    if parts is None or any(("&" in entry or "*" in entry) for entry in parts[1]):
        return parse_yaml(text, path)
    head, entries = parts
    data = parse_yaml(head, path) or {}
    if not isinstance(data, dict) or "stages" in data:
        return parse_yaml(text, path)
    stages: dict = {}
    for entry in entries:
        cached = _ENTRY_VALUES.get(entry)
        if cached is None:
            value = parse_yaml("stages:\n" + entry, path)
            if not (isinstance(value, dict) and list(value) == ["stages"] and isinstance(value["stages"], dict)
                    and len(value["stages"]) == 1):
                return parse_yaml(text, path)
            cached = _ENTRY_VALUES[entry] = pickle.dumps(value["stages"], protocol=5)
        ((name, value),) = pickle.loads(cached).items()
        if name in stages:
            return parse_yaml(text, path)  # a name twice: the whole file's loader says what that means
        stages[name] = value
    data["stages"] = stages
    return data


def parse_yaml_fast(dvc_parse_yaml):
    """A replacement for DVC's ``parse_yaml``: dvc.lock read by the safe loader goes through ``parse_lock``,
    anything else to DVC's own."""

    def parse_yaml(text, path, typ="safe"):
        if typ != "safe" or os.path.basename(os.fspath(path)) != LOCK_NAME:
            return dvc_parse_yaml(text, path, typ=typ)
        return parse_lock(text, path, dvc_parse_yaml)

    return parse_yaml


def modify_yaml_fast(dvc_modify_yaml):
    """A replacement for ``dvc.dvcfile.modify_yaml``: dvc.lock read and written as the module docstring
    says, any other file by ``dvc_modify_yaml`` (DVC's own)."""

    @contextmanager
    def modify_yaml(path, fs=None):
        if os.path.basename(os.fspath(path)) != LOCK_NAME:
            with dvc_modify_yaml(path, fs=fs) as data:
                yield data
            return
        from dvc.utils.serialize._yaml import parse_yaml  # parse_yaml_fast, once installed

        open_fn = fs.open if fs else open
        exists = fs.exists(os.fspath(path)) if fs else os.path.exists(path)
        data = {}
        if exists:
            with open_fn(path, encoding="utf-8") as fd:
                data = parse_yaml(fd.read(), path)
        yield data
        text = lock_text(data)
        with open_fn(path, "w+", encoding="utf-8") as fd:
            fd.write(text)

    return modify_yaml


def install() -> bool:
    """Route DVC's updates of dvc.lock through ``modify_yaml_fast`` and its reads through ``parse_yaml_fast``;
    False (nothing changed) under another DVC version than ``CHECKED_DVC``."""
    import dvc
    import dvc.dvcfile
    import dvc.utils.serialize._yaml as dvc_yaml
    import dvc.utils.strictyaml as dvc_strictyaml

    if dvc.__version__ != CHECKED_DVC:
        print(f"dvc_fast_lock: DVC {dvc.__version__}, not {CHECKED_DVC}: dvc.lock is updated by DVC's own code",
              file=sys.stderr)
        return False
    dvc.dvcfile.modify_yaml = modify_yaml_fast(dvc.dvcfile.modify_yaml)
    # Both modules that call it by name (strictyaml.load reads dvc.lock when DVC collects the stages).
    fast = parse_yaml_fast(dvc_yaml.parse_yaml)
    dvc_yaml.parse_yaml = dvc_strictyaml.parse_yaml = fast
    return True


def main(argv: list[str] | None = None) -> int:
    from dvc.cli import main as dvc_main

    install()
    return dvc_main(sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    sys.exit(main())
