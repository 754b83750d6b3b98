"""Data resolution, verification and download (against local HTTP servers only, never the internet)."""

from __future__ import annotations

import functools
import hashlib
import json
import os
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from script_loader import load_script
from tactile6d.core.errors import DataError
from tactile6d.data import third_party

REPO = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get(third_party.ENV_VAR) or REPO.parent / "shared" / "data")
needs_shared = pytest.mark.skipif(
    not (SHARED / "caddeo2023" / "json" / "objects.json").is_file(),
    reason=f"no data directory at {SHARED} (set {third_party.ENV_VAR} to a copy of shared/data)",
)

# A few small files from both upstream repositories and from every kind of group.
SAMPLE = [
    "caddeo2023/json/objects.json",
    "digit/tacto/config_digit.yml",
    "digit/caddeo2023/background.png",
    "ycb/004_sugar_box/points.xyz",
    "ycb/006_mustard_bottle/collision_caddeo2023/textured_1.obj",
    "caddeo2023/triplets/011_banana/triplet_2/poses_sensors.txt",
]


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args):  # keep pytest output clean
        pass


class _Corrupt(_Quiet):
    """Serves every file with its first byte flipped (right length, wrong bytes)."""

    def do_GET(self):
        path = Path(self.translate_path(self.path))
        if not path.is_file():
            return self.send_error(404)
        body = bytearray(path.read_bytes())
        body[0] ^= 0xFF
        self.send_response(200)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(bytes(body))


class _Truncated(_Quiet):
    """Announces the full length, sends half of the file, then drops the connection."""

    def do_GET(self):
        path = Path(self.translate_path(self.path))
        if not path.is_file():
            return self.send_error(404)
        body = path.read_bytes()
        self.send_response(200)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body[: len(body) // 2])
        self.wfile.flush()
        self.close_connection = True


@pytest.fixture
def serve():
    """``serve(directory, handler)`` -> base URL of a 127.0.0.1 server for that directory."""
    servers = []

    def start(directory: Path, handler=_Quiet) -> str:
        server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(handler, directory=str(directory)))
        threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_address[1]}"

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


@pytest.fixture
def no_env(monkeypatch):
    """Download mode needs $TACTILE6D_DATA unset (CI sets it)."""
    monkeypatch.delenv(third_party.ENV_VAR, raising=False)


def download_cfg(cache: Path, **extra) -> dict:
    return {"data_dir": None, "cache_dir": str(cache), "download_retries": 1, "download_timeout_s": 10, **extra}


def files_under(path: Path) -> list[Path]:
    return sorted(p for p in path.rglob("*") if p.is_file())


# --- manifest -------------------------------------------------------------------------------------


@needs_shared
def test_manifest_matches_the_data_directory_exactly():
    script = load_script("make_data_manifest")
    assert script.build_manifest(SHARED) == third_party.load_manifest()
    # the file on disk is what the script writes, byte for byte (no hand edits)
    assert third_party.MANIFEST_PATH.read_text() == script.dumps(third_party.load_manifest())


def test_manifest_covers_every_needed_file():
    manifest = third_party.load_manifest()
    files = manifest["files"]
    objects = [
        "002_master_chef_can", "004_sugar_box", "006_mustard_bottle", "007_tuna_fish_can", "008_pudding_box",
        "011_banana", "019_pitcher_base", "021_bleach_cleanser", "036_wood_block", "040_large_marker",
    ]
    collision = {"006_mustard_bottle": 4, "019_pitcher_base": 15}  # others: 1 (see shared/data/ycb/README.md)
    expected = {
        "caddeo2023/json/objects.json",
        "digit/tacto/digit.STL",
        "digit/tacto/config_digit.yml",
        "digit/tacto/bg_digit_240_320.jpg",
        "digit/caddeo2023/background.png",
    }
    for obj in objects:
        expected |= {f"ycb/{obj}/textured_simple.obj", f"ycb/{obj}/points.xyz"}
        expected |= {f"ycb/{obj}/collision_caddeo2023/textured_{i}.obj" for i in range(collision.get(obj, 1))}
        expected |= {f"caddeo2023/point_clouds/{obj}/{n}" for n in ("poses_images.txt", "poses_sensors.txt", "angles_database.txt")}
        for k in range(1, 5):
            names = ["Image_heatmap_0.png", "Image_heatmap_1.png", "Image_heatmap_2.png", "poses_sensors.txt", "sensors.off"]
            expected |= {f"caddeo2023/triplets/{obj}/triplet_{k}/{n}" for n in names}
    assert set(files) == expected
    # every file is in exactly one group, and groups name only manifest files
    grouped = [rel for name in third_party.group_names() for rel in third_party.group_files(name)]
    assert sorted(grouped) == sorted(files)
    assert set(third_party.group_files("object:011_banana")) == {
        "ycb/011_banana/textured_simple.obj", "ycb/011_banana/points.xyz",
        "ycb/011_banana/collision_caddeo2023/textured_0.obj",
    }
    assert len(third_party.group_files("triplets:004_sugar_box")) == 20
    for entry in files.values():
        assert manifest["sources"][entry["source"]]["commit"] in {
            "e4e77b3cd8b4e163e349b4456961865c9a6ecd0d", "a21d0c4626d74a546d94859226c2fea348babb6a",
        }
    assert files["digit/tacto/digit.STL"]["upstream_path"] == "meshes/digit.STL"
    assert files["ycb/019_pitcher_base/collision_caddeo2023/textured_14.obj"]["upstream_path"] == (
        "models/019_pitcher_base/textured_14.obj"
    )
    assert files["caddeo2023/triplets/040_large_marker/triplet_3/sensors.off"]["upstream_path"] == (
        "final_triplets/040_large_marker/triplet_3/sensors.off"
    )
    with pytest.raises(DataError, match="unknown data group"):
        third_party.group_files("object:035_power_drill")


# --- resolution -----------------------------------------------------------------------------------


def test_resolution_order_env_then_config_then_download(tmp_path, monkeypatch):
    env_dir, cfg_dir = tmp_path / "env", tmp_path / "cfg"
    env_dir.mkdir()
    cfg_dir.mkdir()
    monkeypatch.setenv(third_party.ENV_VAR, str(env_dir))
    assert third_party.resolve_data_dir({"data_dir": str(cfg_dir)}) == env_dir.resolve()
    monkeypatch.delenv(third_party.ENV_VAR)
    assert third_party.resolve_data_dir({"data_dir": str(cfg_dir)}) == cfg_dir.resolve()
    assert third_party.resolve_data_dir({"data_dir": None}) is None
    monkeypatch.setenv(third_party.ENV_VAR, "")  # an empty variable counts as unset
    assert third_party.resolve_data_dir({"data_dir": None}) is None
    store = third_party.DataStore({"data_dir": None, "cache_dir": str(tmp_path / "cache")})
    assert store.data_dir is None and store.root == (tmp_path / "cache").resolve()


def test_missing_data_directory_names_its_origin(tmp_path, monkeypatch):
    monkeypatch.setenv(third_party.ENV_VAR, str(tmp_path / "nowhere"))
    with pytest.raises(DataError, match=third_party.ENV_VAR):
        third_party.DataStore({"data_dir": None})
    monkeypatch.delenv(third_party.ENV_VAR)
    with pytest.raises(DataError, match="paths.data_dir"):
        third_party.resolve_data_dir({"data_dir": str(tmp_path / "nowhere")})


def test_config_tree_has_the_keys_the_store_reads():
    from tactile6d.core.config import compose_config

    paths = compose_config().paths
    store_keys = {"data_dir", "data_url", "cache_dir", "upstream_url", "download_timeout_s", "download_retries"}
    assert store_keys <= set(paths.keys())
    assert paths.upstream_url == third_party.DEFAULT_UPSTREAM_URL


# --- local data directory -------------------------------------------------------------------------


@needs_shared
def test_local_directory_files_are_verified_once(monkeypatch):
    monkeypatch.setenv(third_party.ENV_VAR, str(SHARED))
    store = third_party.DataStore({"data_dir": None})
    calls = []
    real = third_party._sha256
    monkeypatch.setattr(third_party, "_sha256", lambda p: calls.append(p) or real(p))
    third_party._VERIFIED.clear()
    rel = "ycb/004_sugar_box/textured_simple.obj"
    assert store.path(rel) == SHARED.resolve() / rel
    assert store.path(rel) == SHARED.resolve() / rel
    assert len(calls) == 1
    assert [p.name for p in store.paths("digit")] == ["digit.STL", "config_digit.yml", "bg_digit_240_320.jpg", "background.png"]


@needs_shared
def test_local_directory_missing_or_corrupt_file_is_an_error(tmp_path, monkeypatch):
    rel = "caddeo2023/triplets/011_banana/triplet_2/poses_sensors.txt"
    (tmp_path / rel).parent.mkdir(parents=True)
    monkeypatch.setenv(third_party.ENV_VAR, str(tmp_path))
    store = third_party.DataStore({"data_dir": None})
    with pytest.raises(DataError, match=r"poses_sensors\.txt.*missing"):
        store.path(rel)
    text = (SHARED / rel).read_text()
    (tmp_path / rel).write_text(text.replace("0", "1", 1))  # same size, different bytes
    with pytest.raises(DataError, match=rf"{tmp_path}.*sha256"):
        store.path(rel)
    (tmp_path / rel).write_text(text)  # repaired: the new mtime/bytes are checked again
    assert store.path(rel) == tmp_path.resolve() / rel
    with pytest.raises(DataError, match="not in the data manifest"):
        store.path("ycb/004_sugar_box/textured.obj")


# --- download mode --------------------------------------------------------------------------------


@needs_shared
def test_download_from_a_mirror(tmp_path, serve, no_env):
    base = serve(SHARED)
    store = third_party.DataStore(download_cfg(tmp_path / "cache", data_url=base + "/"), progress=False)
    assert store.url(SAMPLE[0]) == f"{base}/{SAMPLE[0]}"
    got = store.fetch(SAMPLE)
    for rel, path in zip(SAMPLE, got):
        assert path == (tmp_path / "cache" / rel).resolve()
        assert sha256(path) == sha256(SHARED / rel)
    assert len(files_under(tmp_path / "cache")) == len(SAMPLE)  # no temp files left behind
    # a second call uses the cache: a dead mirror does not matter any more
    store2 = third_party.DataStore(download_cfg(tmp_path / "cache", data_url="http://127.0.0.1:9"), progress=False)
    assert store2.path(SAMPLE[1]) == got[1]


@needs_shared
def test_download_uses_the_github_raw_scheme(tmp_path, serve, no_env):
    manifest = third_party.load_manifest()
    fake_github = tmp_path / "github"
    for rel in SAMPLE:
        entry = manifest["files"][rel]
        src = manifest["sources"][entry["source"]]
        dest = fake_github / src["repo"] / src["commit"] / entry["upstream_path"]
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.symlink_to(SHARED.resolve() / rel)
    store = third_party.DataStore(download_cfg(tmp_path / "cache", upstream_url=serve(fake_github)), progress=False)
    assert store.url("digit/tacto/config_digit.yml").endswith(
        "/facebookresearch/tacto/a21d0c4626d74a546d94859226c2fea348babb6a/tacto/config_digit.yml"
    )
    for rel in SAMPLE:
        assert sha256(store.path(rel)) == manifest["files"][rel]["sha256"]
    # fetch_all of a group that is only partly served fails on the first file it cannot get
    with pytest.raises(DataError, match=r"https?://127\.0\.0\.1:\d+/hsp-iit/.*HTTP 404"):
        store.fetch_all(["object:002_master_chef_can"])


def test_default_upstream_is_github_raw_at_the_pinned_commit(tmp_path, no_env):
    store = third_party.DataStore({"data_dir": None, "cache_dir": str(tmp_path)})
    assert store.url("ycb/004_sugar_box/points.xyz") == (
        "https://raw.githubusercontent.com/hsp-iit/multi-tactile-6d-estimation/"
        "e4e77b3cd8b4e163e349b4456961865c9a6ecd0d/models/004_sugar_box/points.xyz"
    )


@needs_shared
def test_corrupt_download_is_an_error_and_leaves_nothing(tmp_path, serve, no_env):
    base = serve(SHARED, _Corrupt)
    store = third_party.DataStore(download_cfg(tmp_path / "cache", data_url=base), progress=False, retry_wait_s=0)
    with pytest.raises(DataError, match=rf"{base}/digit/tacto/config_digit\.yml.*sha256"):
        store.path("digit/tacto/config_digit.yml")
    assert files_under(tmp_path / "cache") == []


@needs_shared
def test_interrupted_download_leaves_nothing(tmp_path, serve, no_env):
    base = serve(SHARED, _Truncated)
    store = third_party.DataStore(download_cfg(tmp_path / "cache", data_url=base), progress=False, retry_wait_s=0)
    with pytest.raises(DataError, match=r"could not download ycb/004_sugar_box/points\.xyz from http.*ended after"):
        store.path("ycb/004_sugar_box/points.xyz")
    assert files_under(tmp_path / "cache") == []


@needs_shared
def test_download_stopped_by_ctrl_c_leaves_nothing(tmp_path, serve, no_env, monkeypatch):
    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(third_party.os, "replace", interrupted)  # the last step of a download, after the temp file is full
    store = third_party.DataStore(download_cfg(tmp_path / "cache", data_url=serve(SHARED)), progress=False)
    with pytest.raises(KeyboardInterrupt):
        store.path("ycb/004_sugar_box/points.xyz")
    assert files_under(tmp_path / "cache") == []


@needs_shared
def test_a_bad_cached_copy_is_replaced(tmp_path, serve, no_env):
    rel = "digit/tacto/config_digit.yml"
    cached = tmp_path / "cache" / rel
    cached.parent.mkdir(parents=True)
    cached.write_text("not the config\n")
    store = third_party.DataStore(download_cfg(tmp_path / "cache", data_url=serve(SHARED)), progress=False)
    assert sha256(store.path(rel)) == sha256(SHARED / rel)


def test_unreachable_server_names_the_url(tmp_path, no_env):
    # port 9 (discard) on localhost: nothing listens there, so the connection is refused at once
    store = third_party.DataStore(download_cfg(tmp_path / "cache", data_url="http://127.0.0.1:9"), progress=False, retry_wait_s=0)
    with pytest.raises(DataError, match=r"http://127\.0\.0\.1:9/caddeo2023/json/objects\.json"):
        store.path("caddeo2023/json/objects.json")
    assert files_under(tmp_path / "cache") == []


def test_manifest_file_is_plain_json():
    # the manifest must be loadable without the package (e.g. by CI scripts)
    manifest = json.loads(third_party.MANIFEST_PATH.read_text())
    assert set(manifest) >= {"sources", "groups", "files"}
    assert all(set(e) == {"size", "sha256", "source", "upstream_path"} for e in manifest["files"].values())
