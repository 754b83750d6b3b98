"""Where a stage's heavy loop runs: local worker processes by default, a Dask cluster when the config names one.

A stage splits its loop into independent tasks and hands them to an ``Executor``:
``executor.map(fn, *iterables)`` calls ``fn(*args)`` for each tuple of ``zip(*iterables)`` and returns
the results **in input order**, whichever worker finished first; ``executor.completed(fn, *iterables)``
yields ``(index, result)`` as each task finishes, for a caller that acts before the last one is in. DVC stays the orchestrator and the
cache: the executor only spreads the work inside one stage, and where the work ran never changes a
result (so config section ``executor`` is no DVC parameter of any stage).

- ``LocalExecutor(workers)``: 1 runs the tasks in this process (no pool, no pickling); more start that
  many worker processes (``concurrent.futures.ProcessPoolExecutor``, spawn context: a forked child would
  inherit half-made torch, JAX or Embree thread pools).
- ``DaskExecutor(address)``: the workers of a running Dask cluster (``distributed.Client(address)``, e.g.
  ``tcp://10.0.0.5:8786``); docs/distributed.md says how to start one and what the workers need.
- ``executor_from_config(cfg, workers)`` picks one from config section ``executor`` (conf/executor/).

What a task may assume: ``fn`` and its arguments are pickled to another process (a module-level
function of an importable module, picklable arguments; large inputs are better read by path or
shipped once per chunk of work than once per item). ``initializer(*initargs)`` has run once in that
process before its first task (e.g. ``optimize.use_cpu_devices``, which must precede any JAX work).
Heavy per-process state (a loaded renderer, a library of estimators) is loaded once per process with
``process_cache(key, factory)``, which works the same in this process, in spawn workers and in Dask
workers. Tasks of one process never run concurrently (a Dask worker started with several threads
still runs one task at a time): the renderer and the estimator are not thread-safe.

Ctrl-C (SIGINT to the terminal's process group) ends the local worker processes at once, task or no
task (``worker_context``), and a local executor closed while an interrupt unwinds ends its workers
instead of waiting for their tasks (``shutdown_pool``): docs/distributed.md, "Ctrl-C".
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import hashlib
import multiprocessing
import multiprocessing.connection
import multiprocessing.context
import os
import pickle
import signal
import sys
import threading
import time
import weakref
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping
from typing import Any, TypeVar

from tqdm import tqdm

from tactile6d.core.errors import ConfigError, on_interrupt

T = TypeVar("T")

# --- per-process state ---------------------------------------------------------------------------------

_CACHE: dict[Hashable, Any] = {}
_SLOTS: dict[Hashable, Hashable] = {}  # slot -> the key that holds it now
_CACHE_LOCK = threading.RLock()
_TASK_LOCK = threading.Lock()  # one task at a time per process (Dask workers may run several threads)
_INITIALIZED: set[str] = set()  # tokens of the initializers that have run in this process


def process_cache(key: Hashable, factory: Callable[[], T], slot: Hashable | None = None) -> T:
    """The value stored under ``key`` in this process, made by ``factory()`` on first use.

    A task calls it to load heavy state once per worker process, e.g.
    ``process_cache(("library", run_token), lambda: load_library(...))``. The key must name everything
    the value depends on (settings, paths; a token per stage run when files may change between runs
    in one process). slot: entries that share a slot replace each other, so that a process keeps at
    most one of them (one variant's estimators at a time): the old entry is dropped before the new one
    is made. Thread-safe; values are shared, not copied.
    """
    with _CACHE_LOCK:
        if key in _CACHE:
            return _CACHE[key]
        if slot is not None and _SLOTS.get(slot, key) != key:
            _CACHE.pop(_SLOTS.pop(slot), None)
        value = factory()
        _CACHE[key] = value
        if slot is not None:
            _SLOTS[slot] = key
        return value


def clear_process_cache() -> None:
    """Forget every ``process_cache`` entry of this process (tests; freeing memory)."""
    with _CACHE_LOCK:
        _CACHE.clear()
        _SLOTS.clear()


def _initializer_token(initializer: Callable | None, initargs: tuple) -> str | None:
    """A name for an initializer call, equal in every process: the digest of its pickle."""
    if initializer is None:
        return None
    return hashlib.sha1(pickle.dumps((initializer, tuple(initargs)))).hexdigest()


def _run_task(init: tuple[str, Callable, tuple] | None, fn: Callable, args: tuple):
    """What a Dask worker runs for one task: the executor's initializer once per process, then ``fn(*args)``."""
    with _TASK_LOCK:
        if init is not None and init[0] not in _INITIALIZED:
            init[1](*init[2])
            _INITIALIZED.add(init[0])
        return fn(*args)


# --- worker processes that Ctrl-C stops --------------------------------------------------------------------

# How long terminated workers get to exit before they are killed (SIGKILL): they hold nothing to save.
_TERMINATE_GRACE_S = 2.0
_WORKERS: weakref.WeakSet = weakref.WeakSet()  # the worker processes this process started (end_worker_processes)


@contextlib.contextmanager
def _sigint_blocked():
    """SIGINT held back in this thread meanwhile (delivered when it ends); a process started meanwhile
    inherits the blocked signal."""
    if not hasattr(signal, "pthread_sigmask"):  # not POSIX: nothing to hold back
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class _WorkerProcess(multiprocessing.context.SpawnProcess):
    """A spawn worker process that SIGINT ends at once, like any program a terminal's Ctrl-C reaches.

    A worker of ``concurrent.futures`` with Python's own SIGINT handler turns the group's Ctrl-C into a
    KeyboardInterrupt inside its task, sends it back as the task's error and takes the next queued task,
    which the parent's shutdown then waits for (issue 33: the ablation lingered 18 s and more). It is
    started with SIGINT blocked, so that a Ctrl-C during its start-up (imports of torch, JAX: seconds)
    waits instead of printing a traceback; ``run`` restores the default action and unblocks it, which
    ends the process there if a Ctrl-C came meanwhile.
    """

    def start(self):
        with _sigint_blocked():
            super().start()
        _WORKERS.add(self)

    def run(self):
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if hasattr(signal, "pthread_sigmask"):
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        super().run()


class _WorkerContext(multiprocessing.context.SpawnContext):
    Process = _WorkerProcess


def worker_context() -> multiprocessing.context.BaseContext:
    """The multiprocessing context of the project's worker pools (``mp_context`` of a
    ``ProcessPoolExecutor``): spawn, with worker processes that Ctrl-C ends at once (``_WorkerProcess``)."""
    return _WorkerContext()


def _interrupted() -> bool:
    """Whether a Ctrl-C or SIGTERM is unwinding (``tactile6d.core.errors.Interrupted`` is a KeyboardInterrupt)."""
    return isinstance(sys.exc_info()[1], KeyboardInterrupt)


def cancel_unless_interrupted(futures: Iterable[concurrent.futures.Future]) -> None:
    """Cancel the futures not yet started, of a pool whose results are no longer wanted (a task raised,
    the caller stopped early), unless a Ctrl-C or SIGTERM is unwinding: then the pool's shutdown
    (``shutdown_pool``) cancels them in its manager thread instead. Cancelled from this thread while the
    workers die of the same Ctrl-C, a future can still be on the manager's list when it marks the pool
    broken: Python before 3.12 then fails to set its error (InvalidStateError, CPython gh-107219) and
    prints the manager thread's traceback."""
    if _interrupted():
        return
    for future in futures:
        future.cancel()


def terminate_workers(processes: Iterable[multiprocessing.process.BaseProcess],
                      grace_s: float = _TERMINATE_GRACE_S) -> None:
    """End these processes now: SIGTERM, then SIGKILL for any still there after ``grace_s`` seconds.
    Their sentinels tell when they are gone, whichever thread reaps them."""
    processes = [p for p in processes if p.exitcode is None]
    if not processes:
        return
    for p in processes:
        with contextlib.suppress(OSError, ValueError):
            p.terminate()
    left = [p.sentinel for p in processes]
    with contextlib.suppress(OSError, ValueError):
        gone = multiprocessing.connection.wait(left, grace_s)
        for p in processes:
            if p.sentinel not in gone:
                p.kill()


def end_worker_processes() -> None:
    """End every worker process of this process's pools that still runs (a pool nobody closed while an
    interrupt unwound): the interpreter would wait for them at exit. Only the pools' workers, not other
    child processes (a Dask ``LocalCluster`` of the caller's)."""
    terminate_workers(list(_WORKERS))


on_interrupt(end_worker_processes)


def free_torn_result(manager: threading.Thread, timeout_s: float = 5.0) -> None:
    """Let a process pool's manager thread end after its workers were killed (``shutdown_pool`` under
    Ctrl-C) while one of them was sending a result.

    A result larger than a pipe holds (a contact patch, a rendered batch: hundreds of kB) leaves the
    manager thread, when its worker is killed mid-send, reading the rest of a message that will never come,
    and the interpreter waits for that thread at exit: the program hangs after its "interrupted" line
    (about one Ctrl-C in three of ``tests/test_interrupt.py``'s patch-reading loop, before this). Zero bytes
    written into the result pipe complete the message; it does not unpickle, the thread marks the pool
    broken and ends. Writes that find the pipe full wait for the thread to read; after ``timeout_s``
    seconds it gives up.
    """
    queue = getattr(manager, "result_queue", None)  # private, as the rest of the pool's insides here
    if queue is None:
        return
    fd = queue._writer.fileno()
    os.set_blocking(fd, False)
    zeros = bytes(1 << 16)
    deadline = time.monotonic() + timeout_s
    while manager.is_alive() and time.monotonic() < deadline:
        try:
            os.write(fd, zeros)
        except BlockingIOError:
            manager.join(0.01)
        except OSError:  # the pipe is closed: nothing left to free
            return
    manager.join(max(0.0, deadline - time.monotonic()))


def shutdown_pool(pool: concurrent.futures.ProcessPoolExecutor) -> None:
    """Shut a process pool down, its queued tasks cancelled: after the running ones finish, or, while a
    Ctrl-C or SIGTERM is unwinding (called from a ``finally`` or an ``__exit__``), at once, its workers
    terminated: nobody will read what they are computing, and the process could not exit before them
    (``concurrent.futures`` joins its workers at interpreter exit)."""
    if not _interrupted():
        pool.shutdown(cancel_futures=True)
        return
    # ``_processes`` (pid -> process) and the manager thread are private, but the only way to reach them
    # before Python 3.14's ``terminate_workers``; shutdown() drops them, so they are read first.
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    terminate_workers(processes)
    if manager is not None:
        # Let it see its workers gone and close its pipes now: left running, it races the interpreter's
        # exit hook of concurrent.futures, which then writes to a closed pipe (a traceback on stderr).
        manager.join(_TERMINATE_GRACE_S)
        if manager.is_alive():  # still reading a result its worker was killed sending
            free_torn_result(manager)


# --- executors ---------------------------------------------------------------------------------------------


class Executor:
    """Runs independent tasks and returns their results in input order; a context manager (``close``)."""

    def completed(self, fn: Callable[..., T], *iterables: Iterable,
                  desc: str | None = None) -> Iterator[tuple[int, T]]:
        """``(i, fn(*args_i))`` for each ``args_i`` of ``zip(*iterables)``, as the workers finish them: in
        any order (input order when the tasks run in this process, each one when the iterator is
        advanced). With ``desc``, a tqdm bar over the tasks as they finish. The first task that raises
        stops it: the others are cancelled and its exception (the original type) is raised here; so are
        the tasks not yet finished when the caller stops iterating (closes the generator)."""
        raise NotImplementedError

    def map(self, fn: Callable[..., T], *iterables: Iterable, desc: str | None = None) -> list[T]:
        """``[fn(*args) for args in zip(*iterables)]``, computed by the workers (``completed``, put back in
        input order)."""
        tasks = list(zip(*iterables))
        out: list = [None] * len(tasks)
        for i, result in self.completed(fn, *zip(*tasks), desc=desc):
            out[i] = result
        return out

    def describe(self) -> str:
        """One line saying where the tasks run, for a stage's log."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the workers (a pool's processes, a cluster connection); the executor is unusable then."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _progress(total: int, desc: str | None) -> tqdm:
    return tqdm(total=total, desc=desc, unit="task", disable=desc is None)


class LocalExecutor(Executor):
    """``workers`` processes of this machine; 1 runs every task in this process.

    initializer(*initargs): run once in each worker process before its first task; with 1 worker, once
    in this process before the first task. The pool starts with the first tasks given to more than one
    worker and is reused by later ones. Its workers die on Ctrl-C (``worker_context``); closed while an
    interrupt unwinds, it terminates them rather than wait for their tasks (``shutdown_pool``).
    """

    def __init__(self, workers: int, initializer: Callable | None = None, initargs: tuple = ()):
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ConfigError(f"a local executor needs a whole number of worker processes >= 1, got {workers!r}")
        self.workers = workers
        self.initializer, self.initargs = initializer, tuple(initargs)
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._initialized = False

    def completed(self, fn, *iterables, desc=None):
        tasks = list(zip(*iterables))
        if self.workers == 1:
            if self.initializer is not None and not self._initialized:
                self.initializer(*self.initargs)
                self._initialized = True
            with _progress(len(tasks), desc) as bar:
                for i, args in enumerate(tasks):
                    result = fn(*args)
                    bar.update(1)
                    yield i, result
            return
        if self._pool is None:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                self.workers, mp_context=worker_context(),
                initializer=self.initializer, initargs=self.initargs)
        futures = [self._pool.submit(fn, *args) for args in tasks]
        index = {future: i for i, future in enumerate(futures)}
        try:
            with _progress(len(tasks), desc) as bar:
                for future in concurrent.futures.as_completed(futures):
                    result = future.result()
                    bar.update(1)
                    yield index[future], result
        finally:  # a task raised or the caller stopped early: drop what has not started
            cancel_unless_interrupted(futures)

    def describe(self) -> str:
        return "this process" if self.workers == 1 else f"{self.workers} local worker processes"

    def close(self) -> None:
        if self._pool is not None:
            pool, self._pool = self._pool, None
            shutdown_pool(pool)


class DaskExecutor(Executor):
    """The workers of a running Dask cluster, reached through its scheduler at ``address``.

    address: ``tcp://host:port`` (``dask scheduler`` listens on 8786). timeout_s: how long to wait for the
    scheduler to answer; a ConfigError naming the address when it does not. The cluster decides how
    many tasks run at once (start its workers with ``--nthreads 1``: see the module docstring).

    initializer(*initargs) runs once per worker process, before the first task of this executor that
    the process runs: each task carries it (a few bytes) and a per-process registry skips it when it has
    run. Unlike ``client.run`` this also covers workers that join or restart later, and unlike a
    ``WorkerPlugin`` it leaves nothing registered on a shared scheduler after the stage.
    Every task is submitted with ``pure=False``: equal arguments are separate tasks, never merged.
    """

    def __init__(self, address: str, initializer: Callable | None = None, initargs: tuple = (),
                 timeout_s: float = 10.0):
        from distributed import Client

        self.address = address
        _probe_scheduler(address, timeout_s)
        self.client = Client(address, timeout=timeout_s, set_as_default=False)
        token = _initializer_token(initializer, initargs)
        self._init = None if token is None else (token, initializer, tuple(initargs))

    def completed(self, fn, *iterables, desc=None):
        from distributed import as_completed

        tasks = list(zip(*iterables))
        futures = [self.client.submit(_run_task, self._init, fn, args, pure=False) for args in tasks]
        index = {future.key: i for i, future in enumerate(futures)}
        finished = False
        try:
            with _progress(len(tasks), desc) as bar:
                for future, result in as_completed(futures, loop=self.client.loop, with_results=True):
                    bar.update(1)
                    yield index[future.key], result
            finished = True
        finally:
            if not finished:  # a task raised or the caller stopped early
                self.client.cancel(futures)

    def describe(self) -> str:
        threads = self.client.nthreads()  # worker address -> its threads
        return f"Dask cluster at {self.address}: {len(threads)} workers, {sum(threads.values())} threads"

    def close(self) -> None:
        self.client.close()


def _probe_scheduler(address: str, timeout_s: float) -> None:
    """Raise ConfigError unless a Dask scheduler answers at ``address`` within ``timeout_s`` seconds.

    A separate connection, before the Client is made: a Client whose connection failed still tries to
    close itself when collected, which blocks for twice the timeout and prints a traceback.
    """
    from distributed.comm import connect

    try:
        asyncio.get_running_loop()
        return  # called from inside an event loop (a notebook): leave the check to the Client
    except RuntimeError:
        pass

    async def handshake():
        comm = await connect(address, timeout=timeout_s)
        await comm.close()

    try:
        asyncio.run(asyncio.wait_for(handshake(), timeout_s + 1.0))
    except Exception as exc:  # refused, timed out, a bad address, something else answering
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ConfigError(
            f"executor.address {address!r}: no Dask scheduler reached there within {timeout_s:g} s ({reason}); "
            "start one (`dask scheduler`, docs/distributed.md) or set executor.address=null to run locally"
        ) from None


def executor_from_config(cfg: Mapping, workers: int, initializer: Callable | None = None,
                         initargs: tuple = ()) -> Executor:
    """The executor config section ``executor`` asks for (conf/executor/default.yaml).

    ``executor.address`` null: ``LocalExecutor(workers)`` (the stage's own worker count, e.g.
    ``render.workers``); a scheduler address: ``DaskExecutor`` on it, where ``workers`` is ignored (the
    cluster decides). ConfigError for a bad value, or when the scheduler does not answer within
    ``executor.timeout_s`` seconds.
    """
    section = cfg["executor"] if "executor" in cfg else {}
    address = section.get("address")
    timeout_s = section.get("timeout_s", 10.0)
    if isinstance(timeout_s, bool) or not isinstance(timeout_s, (int, float)) or not timeout_s > 0:
        raise ConfigError(f"executor.timeout_s must be a positive number of seconds, got {timeout_s!r}")
    if address is None:
        return LocalExecutor(workers, initializer, initargs)
    if not isinstance(address, str) or not address.strip():
        raise ConfigError(f"executor.address must be null or a Dask scheduler address such as "
                          f"'tcp://10.0.0.5:8786', got {address!r}")
    return DaskExecutor(address.strip(), initializer, initargs, float(timeout_s))


def map_objects(task: Callable, names: list[str], cfg: Mapping, objects_dir, workers: int, workers_key: str,
                desc: str) -> list:
    """``task(name, cfg, objects_dir)`` for every object name, one executor task each (``executor_from_config``
    with at most ``workers`` local processes, never more than there are names) -> the results in name order.
    ``workers_key``: the config key ``workers`` came from, named in the ConfigError when it is below 1; desc:
    the progress bar's label (shown for more than one name). The per-object stages' ``--distractors`` run:
    each object is one task, since its work runs on one core."""
    if workers < 1:
        raise ConfigError(f"{workers_key} must be >= 1, got {workers}")
    with executor_from_config(cfg, max(1, min(workers, len(names)))) as executor:
        return executor.map(task, names, [cfg] * len(names), [objects_dir] * len(names),
                            desc=desc if len(names) > 1 else None)
