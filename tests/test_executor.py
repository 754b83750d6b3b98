"""tactile6d.runtime.executor: local processes and a real Dask cluster on localhost give the same results, in
order; the initializer and the per-process memo run once per process; render_database and ablation
write the same artifacts through either."""

import concurrent.futures
import hashlib
import json
import os
import struct

import numpy as np
import pytest
from omegaconf import OmegaConf

from stages import ablation, prepare_object, render_database, sample_surface
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError, InputError
from tactile6d.core.geometry import make_pose, rotvec_to_rotmat
from tactile6d.core.sensor import contact_normals, contact_points
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.runtime import executor as ex

# --- tasks (module level: the workers import this module to run them) ----------------------------------

_INITIALIZED = []  # per process: the initializer's arguments, once per call
_MADE = []  # per process: how many times the memo's factory ran


def initializer(tag):
    _INITIALIZED.append(tag)


def task(i, x):
    """-> (i, x squared, this process, its initializer calls, how many times the memo was built)."""
    value = ex.process_cache(("test_executor", "memo"), lambda: _MADE.append(1) or len(_MADE))
    return i, x * x, os.getpid(), list(_INITIALIZED), value


_CALLS = []  # per process: the arguments ``record`` was called with


def record(i):
    _CALLS.append(i)
    return i


def failing(i):
    if i == 3:
        raise InputError(f"task {i} refuses")
    return i


def check_results(results, n):
    assert [r[0] for r in results] == list(range(n))  # input order, whoever finished first
    assert [r[1] for r in results] == [x * x for x in range(n)]
    for pid in {r[2] for r in results}:
        mine = [r for r in results if r[2] == pid]
        assert all(r[3] == ["tag"] for r in mine), mine  # the initializer ran once in that process, first
        assert all(r[4] == 1 for r in mine), mine  # the memo was built once in that process


# --- the local executor -----------------------------------------------------------------------------------


@pytest.fixture
def fresh_process_state():
    ex.clear_process_cache()
    _INITIALIZED.clear()
    _MADE.clear()
    _CALLS.clear()
    yield
    ex.clear_process_cache()
    _INITIALIZED.clear()
    _MADE.clear()
    _CALLS.clear()


def test_one_local_worker_runs_in_this_process(fresh_process_state):
    with ex.LocalExecutor(1, initializer, ("tag",)) as pool:
        first = pool.map(task, range(5), range(5))
        second = pool.map(task, range(5, 8), range(5, 8), desc="second")
    check_results(first + second, 8)
    assert {r[2] for r in first + second} == {os.getpid()}
    assert pool.describe() == "this process"


def test_completed_hands_each_result_over_as_it_is_made(fresh_process_state):
    """In this process the tasks run in order, each when the caller asks for the next result."""
    with ex.LocalExecutor(1) as pool:
        results = pool.completed(record, range(5))
        assert next(results) == (0, 0) and _CALLS == [0]
        assert next(results) == (1, 1) and _CALLS == [0, 1]
        results.close()  # the caller stops: the rest never runs
        assert _CALLS == [0, 1]
        assert list(pool.completed(record, [7, 8])) == [(0, 7), (1, 8)]


@pytest.mark.slow  # worker processes: out of the quick subset
def test_two_local_workers_give_the_same_results_in_order(fresh_process_state):
    n = 24
    with ex.LocalExecutor(2, initializer, ("tag",)) as pool:
        results = pool.map(task, range(n), range(n))
        assert pool.map(task, [], []) == []
        with pytest.raises(InputError, match="task 3 refuses"):  # the task's own error, in this process
            pool.map(failing, range(8))
        assert [r[0] for r in pool.map(task, range(3), range(3))] == [0, 1, 2]  # and the pool still works
        finished = dict(pool.completed(task, range(n), range(n)))  # index -> result, in finishing order
        early = pool.completed(task, range(n), range(n))
        first, _ = next(early)
        early.close()  # stopping early cancels what has not started; the pool goes on
        assert [r[0] for r in pool.map(task, range(3), range(3))] == [0, 1, 2]
    check_results(results, n)
    assert sorted(finished) == list(range(n)) and 0 <= first < n
    assert [finished[i][:2] for i in range(n)] == [r[:2] for r in results]
    assert os.getpid() not in {r[2] for r in results}
    assert _INITIALIZED == [] and _MADE == []  # nothing ran here
    with ex.LocalExecutor(1) as pool:
        assert [r[:2] for r in pool.map(task, range(n), range(n))] == [r[:2] for r in results]
        with pytest.raises(InputError, match="task 3 refuses"):
            pool.map(failing, range(8))


def test_process_cache_slots_keep_one_entry(fresh_process_state):
    built = []
    assert ex.process_cache("a", lambda: built.append("a") or "A", slot="s") == "A"
    assert ex.process_cache("a", lambda: built.append("a") or "A2", slot="s") == "A"  # cached
    assert ex.process_cache("b", lambda: built.append("b") or "B", slot="s") == "B"  # replaces a
    assert ex.process_cache("a", lambda: built.append("a") or "A3", slot="s") == "A3"  # a was dropped
    assert ex.process_cache("c", lambda: "C") == "C" and ex.process_cache("c", lambda: "C2") == "C"  # no slot
    assert built == ["a", "b", "a"]


def torn_pool() -> tuple:
    """A one-worker pool whose manager thread reads a torn result: what a worker killed mid-send leaves (a
    message header announcing 1 MB, one byte of it). -> (the pool, its manager thread)."""
    pool = concurrent.futures.ProcessPoolExecutor(1, mp_context=ex.worker_context())
    assert pool.submit(abs, -1).result() == 1  # the worker and the manager thread are up
    manager = pool._executor_manager_thread
    os.write(manager.result_queue._writer.fileno(), struct.pack("!i", 1 << 20) + b"\x80")
    manager.join(0.5)
    assert manager.is_alive()  # stuck in the read
    return pool, manager


@pytest.mark.slow
def test_a_pool_thread_left_reading_a_torn_result_is_freed():
    """free_torn_result completes the torn message with zeros: the manager thread marks the pool broken
    and ends."""
    pool, manager = torn_pool()
    try:
        ex.free_torn_result(manager)
        assert not manager.is_alive()
        with pytest.raises(concurrent.futures.process.BrokenProcessPool):
            pool.submit(abs, -1).result()
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


@pytest.mark.slow
def test_a_pool_shut_down_under_ctrl_c_frees_a_torn_result():
    """Under a Ctrl-C, shutdown_pool kills the workers and leaves no manager thread behind, even one
    reading a torn result (the interpreter would wait for it at exit: the program would hang)."""
    pool, manager = torn_pool()
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt:
        ex.shutdown_pool(pool)
    assert not manager.is_alive()


@pytest.mark.slow
def test_config_picks_the_executor_and_rejects_bad_values():
    cfg = compose_config()
    assert cfg.executor.address is None
    with ex.executor_from_config(cfg, 3) as pool:
        assert isinstance(pool, ex.LocalExecutor) and pool.workers == 3
    for bad in (0, -1, 1.5, "2"):
        with pytest.raises(ConfigError, match="worker processes"):
            ex.executor_from_config(cfg, bad)
    for overrides, match in ((["executor.address=''"], "executor.address must be"),
                             (["executor.timeout_s=0"], "executor.timeout_s"),
                             (["executor.address=not-an-address"], "no Dask scheduler reached")):
        with pytest.raises(ConfigError, match=match):
            ex.executor_from_config(compose_config(overrides), 2)


@pytest.mark.slow
def test_an_unreachable_scheduler_is_a_clear_error():
    import socket

    with socket.socket() as s:  # a port that nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    cfg = compose_config([f"executor.address={address}", "executor.timeout_s=1"])
    with pytest.raises(ConfigError) as error:
        ex.executor_from_config(cfg, 2)
    message = str(error.value)
    assert address in message and "within 1 s" in message and "executor.address=null" in message


# --- a real Dask cluster on localhost ---------------------------------------------------------------------


@pytest.mark.slow  # a Dask cluster's worker processes: out of the quick subset
def test_dask_gives_the_local_results_in_order(dask_cluster, fresh_process_state):
    n = 24
    cfg = compose_config([f"executor.address={dask_cluster}"])
    with ex.executor_from_config(cfg, 99, initializer, ("tag",)) as pool:
        assert isinstance(pool, ex.DaskExecutor)
        assert "2 workers, 2 threads" in pool.describe()
        results = pool.map(task, range(n), range(n), desc="dask")
        again = pool.map(task, [5, 5], [5, 5])  # equal arguments are two tasks, not one
        finished = dict(pool.completed(task, range(6), range(6)))
        with pytest.raises(InputError, match="task 3 refuses"):
            pool.map(failing, range(8))
    check_results(results, n)
    assert [r[:2] for r in again] == [(5, 25), (5, 25)]
    assert {i: r[:2] for i, r in finished.items()} == {i: (i, i * i) for i in range(6)}
    assert os.getpid() not in {r[2] for r in results}
    with ex.LocalExecutor(1, initializer, ("tag",)) as pool:
        assert [r[:2] for r in pool.map(task, range(n), range(n))] == [r[:2] for r in results]


def md5(path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_render_database_through_dask_writes_the_same_file(dask_cluster, data_dir, tmp_path, monkeypatch):
    """prim_sphere, 70 points, in 3 tasks of 32 poses: on the cluster, in 2 local processes, in tasks of 7
    poses, in this process. The same images; the same file, byte for byte, for the same config (the
    file stamps the render section, render.workers included)."""
    common = ["--object", "prim_sphere", f"paths.data_dir={data_dir}", "sample.M=70"]
    local = tmp_path / "local"
    assert prepare_object.main(common + [f"paths.artifacts_dir={local}", "prepare.collision=hull",
                                         "prepare.n_metric_points=50"]) == 0
    assert sample_surface.main(common + [f"paths.artifacts_dir={local}"]) == 0
    runs = {"local": ["render.workers=2"], "dask": [f"executor.address={dask_cluster}"],
            "chunks-of-7": ["render.workers=2"], "this-process": ["render.workers=1"]}
    files = {}
    for label, overrides in runs.items():
        root = tmp_path / label
        if root != local:
            root.mkdir()
            for kind in ("objects", "surfaces"):
                (root / kind).symlink_to(local / kind)
        with monkeypatch.context() as m:
            if label == "chunks-of-7":
                m.setattr(render_database, "CHUNK", 7)
            assert render_database.main(common + [f"paths.artifacts_dir={root}", *overrides]) == 0
        files[label] = layout.database_file(root, "prim_sphere")
    reference = read_artifact(files["local"], "database")
    assert reference["mask_pixels"].shape == (70,) and (reference["mask_pixels"] > 0).all()
    for label, path in files.items():
        other = read_artifact(path, "database")
        assert other.data.keys() == reference.data.keys()
        for key in reference.data:
            np.testing.assert_array_equal(other[key], reference[key], err_msg=f"{label}: {key}")
    # HDF5 writes no timestamps: equal datasets and config make equal files
    assert md5(files["dask"]) == md5(files["local"]) == md5(files["chunks-of-7"])
    assert read_artifact(files["this-process"], "database").config["render"]["workers"] == 1


@pytest.fixture(scope="module")
def tiny_scenes(tmp_path_factory, data_dir):
    """prim_box's artifacts with a tiny untrained autoencoder and a set of 3 three-sensor scenes."""
    from test_estimator import apart_sensor_poses, write_tiny_autoencoder

    root = tmp_path_factory.mktemp("artifacts")
    common = ["--object", "prim_box", f"paths.artifacts_dir={root}"]
    assert prepare_object.main(common + ["prepare.collision=hull", "prepare.n_metric_points=200"]) == 0
    assert sample_surface.main(common + ["sample.M=300"]) == 0
    write_tiny_autoencoder(root, 300, "prim_box")
    surface = read_artifact(layout.surface_file(root, "prim_box"), "surface")
    poses, sensors = [], []
    for k, start in enumerate((0, 10, 40)):
        T_true = make_pose(rotvec_to_rotmat([0.2, 0.5 * k, -0.4]), [0.1, 0.0, 0.2 + 0.1 * k])
        poses.append(T_true)
        sensors.append(T_true @ apart_sensor_poses(surface, start))
    sensors = np.stack(sensors)
    write_artifact(layout.scenes_file(root, "tiny"), "scenes", {
        "names": np.array([f"prim_box/scene_{k}" for k in range(3)]), "objects": np.array(["prim_box"] * 3),
        "T_world_object": np.stack(poses), "T_world_sensors": sensors,
        "images": np.full((3, 3, 320, 240, 3), (97, 105, 100), np.uint8), "contact_points": contact_points(sensors),
        "contact_normals": contact_normals(sensors), "contact_types": np.zeros((3, 3), int)})
    return root


def without_timings(results: dict) -> dict:
    return {name: {L: {k: v for k, v in summary.items() if k != "time_s_median"} for L, summary in by_L.items()}
            for name, by_L in results.items()}


@pytest.mark.slow
def test_ablation_through_dask_gives_the_same_metrics(dask_cluster, tiny_scenes, data_dir, tmp_path):
    cfg = compose_config([f"paths.artifacts_dir={tiny_scenes}", f"paths.data_dir={data_dir}", "select.N=200",
                          "select.delta_h=3.2", "select.delta_h_max=3.2", "select.contacts=landmark"])
    OmegaConf.set_struct(cfg, False)
    cfg.ablation.variants = {"paper": {"select": {"delta_d_rule": "paper"}, "rank": {"refine": False}},
                             "normals": {"select": {"normal_tol_deg": 20.0}, "optimize": {"normal_weight": 0.01}},
                             "paper_again": {"rank": {"refine": False}, "select": {"delta_d_rule": "paper"}}}
    cfg.ablation.curves, cfg.ablation.only_on, cfg.ablation.variants_on = ["normals"], {}, {}
    cfg.ablation.curves_on = ["tiny"]
    OmegaConf.save(cfg, tmp_path / "params.yaml")
    metrics = layout.metrics_file(tiny_scenes, "ablation_tiny")
    results = {}
    for label, overrides in (("local-1", ["ablation.workers=1"]), ("dask", [f"executor.address={dask_cluster}"])):
        assert ablation.main(["--scene-set", "tiny", "--params", str(tmp_path / "params.yaml"), *overrides]) == 0
        results[label] = json.loads(metrics.read_text())
    assert set(results["dask"]) == {"paper", "normals", "paper_again"}
    assert set(results["dask"]["normals"]) == {"L1", "L2", "L3"}
    assert results["dask"]["normals"]["L3"]["time_s_median"] > 0
    assert without_timings(results["dask"]) == without_timings(results["local-1"])
    # and the same JSON text, but for the timings
    assert json.dumps(without_timings(results["dask"]), sort_keys=True) == json.dumps(
        without_timings(results["local-1"]), sort_keys=True)
