"""`python -m dvc` with a faster update of dvc.lock: what `make reproduce` runs DVC through.

    python scripts/dvc_fast_lock.py repro [options]      # any dvc command line, as `python -m dvc`

DVC 3.67 updates dvc.lock after every stage it runs by parsing the whole file with ruamel.yaml's
round-trip loader (pure Python, so that comments survive) and writing the whole file back with ruamel's
pure-Python emitter: 3.4 s per stage at this pipeline's lock of 509 KB on the 2-core machine (2.1 s
reading, 1.3 s writing), over 5 minutes of a full run's 102 stages (docs/reproducibility.md). The lock
has no comments to keep: DVC writes it alone. Here, for dvc.lock only, the update

- reads the file with DVC's own safe loader (ruamel's libyaml parser, 0.35 s), whose values are those
  the round-trip loader gives (both YAML 1.2);
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


def modify_yaml_fast(dvc_modify_yaml):
    """A replacement for ``dvc.dvcfile.modify_yaml``: dvc.lock read and written as the module docstring
    says, any other file by ``dvc_modify_yaml`` (DVC's own)."""

    @contextmanager
    def modify_yaml(path, fs=None):
        if os.path.basename(os.fspath(path)) != LOCK_NAME:
            with dvc_modify_yaml(path, fs=fs) as data:
                yield data
            return
        from dvc.utils.serialize._yaml import parse_yaml

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
    """Route DVC's updates of dvc.lock through ``modify_yaml_fast``; False (nothing changed) under another
    DVC version than ``CHECKED_DVC``."""
    import dvc
    import dvc.dvcfile

    if dvc.__version__ != CHECKED_DVC:
        print(f"dvc_fast_lock: DVC {dvc.__version__}, not {CHECKED_DVC}: dvc.lock is updated by DVC's own code",
              file=sys.stderr)
        return False
    dvc.dvcfile.modify_yaml = modify_yaml_fast(dvc.dvcfile.modify_yaml)
    return True


def main(argv: list[str] | None = None) -> int:
    from dvc.cli import main as dvc_main

    install()
    return dvc_main(sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    sys.exit(main())
