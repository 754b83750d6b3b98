"""Where the third-party data files come from, and proof that they are the expected bytes.

The project reads YCB meshes and points, DIGIT assets and the paper's evaluation triplets by their
path relative to a *data directory* laid out like ``shared/data`` (e.g. ``ycb/004_sugar_box/points.xyz``).
``tactile6d/data/data_manifest.json`` lists each of those files with its size, sha256 and upstream origin.

Resolution order (``resolve_data_dir``):
1. the environment variable ``TACTILE6D_DATA``;
2. the config key ``paths.data_dir``;
3. neither: download mode. Files are fetched into ``paths.cache_dir`` from ``paths.data_url`` (a mirror
   with the data directory's layout) when set, else from the upstream GitHub repositories at the
   pinned commits (``paths.upstream_url``/<repo>/<commit>/<path>).

Every file handed out has been checked against the manifest, so a stale or partial copy fails loudly
here instead of giving silently different results downstream.

    store = DataStore(cfg.paths)
    mesh = store.path("ycb/004_sugar_box/textured_simple.obj")
    store.fetch_all(["digit", *object_groups("004_sugar_box")])
"""

from __future__ import annotations

import hashlib
import http.client
import json
import os
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterable, Mapping
from functools import lru_cache
from pathlib import Path

from tactile6d.core.errors import DataError

ENV_VAR = "TACTILE6D_DATA"
MANIFEST_PATH = Path(__file__).resolve().parent / "data_manifest.json"
DEFAULT_UPSTREAM_URL = "https://raw.githubusercontent.com"
DEFAULT_TIMEOUT_S = 60.0
DEFAULT_RETRIES = 3

# (resolved path, size, mtime_ns) -> True for files whose sha256 already matched in this process.
# Keyed on size and mtime so that a file replaced on disk is hashed again.
_VERIFIED: dict[tuple[str, int, int], bool] = {}


@lru_cache(maxsize=1)
def load_manifest() -> dict:
    """The packaged manifest: ``{"sources", "groups", "files"}`` (see scripts/make_data_manifest.py)."""
    try:
        return json.loads(MANIFEST_PATH.read_text())
    except (OSError, ValueError) as exc:
        raise DataError(f"cannot read the data manifest {MANIFEST_PATH}: {exc}") from exc


def group_names() -> list[str]:
    """All group names: ``meta``, ``digit``, ``object:<obj>``, ``triplets:<obj>``, ``database:<obj>``."""
    return list(load_manifest()["groups"])


def group_files(group: str) -> list[str]:
    """The relative paths in one group."""
    groups = load_manifest()["groups"]
    if group not in groups:
        raise DataError(f"unknown data group {group!r}; known groups: {', '.join(groups)}")
    return list(groups[group])


def object_groups(obj: str) -> list[str]:
    """The groups of one object: its meshes and points, its evaluation triplets, its contact database."""
    return [f"object:{obj}", f"triplets:{obj}", f"database:{obj}"]


def _get(paths_cfg: Mapping | None, key: str, default=None):
    """``paths_cfg[key]`` for a DictConfig or a dict, or ``default`` when absent or null."""
    if paths_cfg is None:
        return default
    value = paths_cfg.get(key, None)
    return default if value is None else value


def resolve_data_dir(paths_cfg: Mapping | None) -> Path | None:
    """The local data directory (``$TACTILE6D_DATA``, then ``paths.data_dir``), or None for download mode.

    ``~`` is expanded; a relative path is taken from the current directory (the repository root when
    run through the Makefile or DVC).

    A directory that is named but does not exist is an error rather than a fall-through to download
    mode, because a typo would otherwise silently trigger a 46 MB download.
    """
    env = os.environ.get(ENV_VAR, "")
    if env:
        origin, raw = f"environment variable {ENV_VAR}", env
    elif _get(paths_cfg, "data_dir"):
        origin, raw = "config key paths.data_dir", str(_get(paths_cfg, "data_dir"))
    else:
        return None
    path = Path(raw).expanduser().resolve()
    if not path.is_dir():
        raise DataError(
            f"data directory {path} (from {origin}) does not exist; point it at a copy of shared/data, "
            f"or unset it to download the files into paths.cache_dir"
        )
    return path


def _sha256(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def _check(path: Path, entry: dict) -> str | None:
    """None if ``path`` holds the manifest's bytes, else a short reason. Results are memoised per process."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key in _VERIFIED:
        return None
    if st.st_size != entry["size"]:
        return f"size {st.st_size} bytes, expected {entry['size']}"
    try:
        if _sha256(path) != entry["sha256"]:
            return "sha256 differs from the manifest"
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
    _VERIFIED[key] = True
    return None


class DataStore:
    """Verified local paths of the project's third-party files.

    ``paths_cfg`` is the ``paths`` config section (DictConfig or dict) with ``data_dir``, ``data_url``,
    ``cache_dir`` and optionally ``upstream_url``, ``download_timeout_s``, ``download_retries``.
    """

    def __init__(self, paths_cfg: Mapping | None, *, progress: bool = True, retry_wait_s: float = 1.0):
        self.manifest = load_manifest()
        self.data_dir = resolve_data_dir(paths_cfg)
        self.cache_dir = Path(str(_get(paths_cfg, "cache_dir", "~/.cache/tactile6d"))).expanduser().resolve()
        self.data_url = _get(paths_cfg, "data_url")
        self.upstream_url = str(_get(paths_cfg, "upstream_url", DEFAULT_UPSTREAM_URL)).rstrip("/")
        self.timeout_s = float(_get(paths_cfg, "download_timeout_s", DEFAULT_TIMEOUT_S))
        self.retries = int(_get(paths_cfg, "download_retries", DEFAULT_RETRIES))
        self.progress = progress
        self.retry_wait_s = retry_wait_s

    @property
    def root(self) -> Path:
        """The directory the returned paths lie in: the data directory, or the download cache."""
        return self.data_dir if self.data_dir is not None else self.cache_dir

    def _entry(self, relpath: str) -> dict:
        entry = self.manifest["files"].get(relpath)
        if entry is None:
            raise DataError(
                f"{relpath!r} is not in the data manifest {MANIFEST_PATH}; if it is a new input, add it to "
                f"scripts/make_data_manifest.py and regenerate the manifest"
            )
        return entry

    def url(self, relpath: str) -> str:
        """Where download mode fetches ``relpath`` from: the mirror when ``data_url`` is set, else upstream."""
        entry = self._entry(relpath)
        if self.data_url:
            return f"{str(self.data_url).rstrip('/')}/{urllib.parse.quote(relpath)}"
        src = self.manifest["sources"][entry["source"]]
        return f"{self.upstream_url}/{src['repo']}/{src['commit']}/{urllib.parse.quote(entry['upstream_path'])}"

    def path(self, relpath: str) -> Path:
        """The verified local path of ``relpath``, downloading it into the cache first in download mode."""
        return self.fetch([relpath])[0]

    def paths(self, group: str) -> list[Path]:
        """The verified local paths of every file in ``group`` (e.g. ``"object:004_sugar_box"``)."""
        return self.fetch(group_files(group))

    def fetch_all(self, groups: Iterable[str] | None = None) -> list[Path]:
        """Verify (and in download mode fetch) every file of ``groups``; all groups when None."""
        names = group_names() if groups is None else list(groups)
        relpaths = list(dict.fromkeys(rel for name in names for rel in group_files(name)))
        return self.fetch(relpaths)

    def fetch(self, relpaths: list[str]) -> list[Path]:
        """Verified local paths of ``relpaths``, in order; downloads the missing ones as one batch."""
        entries = [self._entry(rel) for rel in relpaths]
        if self.data_dir is not None:
            for rel, entry in zip(relpaths, entries):
                reason = _check(self.data_dir / rel, entry)
                if reason is not None:
                    raise DataError(
                        f"data file {rel} in data directory {self.data_dir}: {reason}; restore it from a copy "
                        f"of shared/data (or unset {ENV_VAR} and paths.data_dir to download verified copies)"
                    )
            return [self.data_dir / rel for rel in relpaths]

        todo = []
        for rel, entry in zip(relpaths, entries):
            target = self.cache_dir / rel
            reason = _check(target, entry)
            if reason is not None:
                # The cache is ours: a bad cached copy (e.g. edited by hand) is replaced, not reported.
                target.unlink(missing_ok=True)
                todo.append(rel)
        if todo:
            self._download_batch(todo)
        return [self.cache_dir / rel for rel in relpaths]

    def _download_batch(self, relpaths: list[str]) -> None:
        from tqdm import tqdm

        total = sum(self._entry(rel)["size"] for rel in relpaths)
        with tqdm(
            total=total, unit="B", unit_scale=True, desc=f"tactile6d data ({len(relpaths)} files)",
            disable=not self.progress,
        ) as bar:
            for rel in relpaths:
                self._download(rel, bar)

    def _download(self, relpath: str, bar) -> None:
        """Fetch one file with retries; it appears at its cache path only once its sha256 matched."""
        entry, url = self._entry(relpath), self.url(relpath)
        target = self.cache_dir / relpath
        target.parent.mkdir(parents=True, exist_ok=True)
        last = ""
        for attempt in range(self.retries + 1):
            if attempt:
                time.sleep(self.retry_wait_s * 2 ** (attempt - 1))
            try:
                self._download_once(url, target, entry, bar)
                return
            except urllib.error.HTTPError as exc:
                last = f"HTTP {exc.code} {exc.reason}"
                if 400 <= exc.code < 500 and exc.code not in (408, 429):
                    break  # a wrong URL will not get better by asking again
            except _ChecksumMismatch as exc:
                last = str(exc)
            except (urllib.error.URLError, http.client.HTTPException, OSError) as exc:
                last = f"{type(exc).__name__}: {getattr(exc, 'reason', exc)}"
            except ValueError as exc:  # urllib's answer to a malformed URL, e.g. a data_url without http://
                last = str(exc)
                break
        where = f"the mirror paths.data_url={self.data_url}" if self.data_url else "GitHub"
        raise DataError(
            f"could not download {relpath} from {url} ({last}); check the network and {where}, "
            f"or set {ENV_VAR} to a local copy of shared/data"
        )

    def _download_once(self, url: str, target: Path, entry: dict, bar) -> None:
        """One attempt: stream to a temp file next to ``target``, check it, then rename it into place.

        The temp file is removed on any failure (including KeyboardInterrupt), so an interrupted
        download never leaves a file behind, and the progress bar is wound back by what it counted.
        """
        fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".part")
        tmp = Path(tmp_name)
        digest, nbytes = hashlib.sha256(), 0
        try:
            with os.fdopen(fd, "wb") as out, urllib.request.urlopen(url, timeout=self.timeout_s) as resp:
                while block := resp.read(1 << 16):
                    out.write(block)
                    digest.update(block)
                    nbytes += len(block)
                    bar.update(len(block))
            # urllib does not always notice a connection cut short, so the length is checked here too.
            if nbytes < entry["size"]:
                raise _ChecksumMismatch(f"transfer ended after {nbytes} of {entry['size']} bytes")
            if nbytes != entry["size"] or digest.hexdigest() != entry["sha256"]:
                raise _ChecksumMismatch(
                    f"got {nbytes} bytes whose sha256 does not match the manifest's "
                    f"({entry['size']} bytes, sha256 {entry['sha256'][:12]}...)"
                )
            os.replace(tmp, target)
        except BaseException:
            tmp.unlink(missing_ok=True)
            bar.update(-nbytes)
            raise
        st = target.stat()
        _VERIFIED[(str(target.resolve()), st.st_size, st.st_mtime_ns)] = True


class _ChecksumMismatch(Exception):
    """A download completed but its bytes are not the manifest's."""
