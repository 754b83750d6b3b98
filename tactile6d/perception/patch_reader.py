"""Contact patches read in worker processes, so that a caller can go on working while they are read.

Reading one image's contact patch (``contact_patch.image_to_patch``) takes about 10 ms on one core of the
2-core machine, and threads of one process barely share it: two threads read a frame's images 1.15-1.27
times as fast as one (measured 2026-11-29, the tracking sequences' images), the rest waits on the GIL.
``PatchReader`` reads them in ``processes`` spawn worker processes instead (``runtime.executor.worker_context``:
Ctrl-C ends them at once), one task per image, each brought to its no-contact image's light first. The
tracker submits a frame's images there and follows the frame before meanwhile (``Tracker.track``).

A patch read in a worker is the patch ``image_to_patch`` reads in this process, bit for bit: the same code
on the same inputs (``tests/test_patch_reader.py``).
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Sequence

import numpy as np

from tactile6d.core.errors import ConfigError
from tactile6d.perception import photometric
from tactile6d.perception.contact_patch import ContactPatch, PatchModel, image_to_patch
from tactile6d.runtime.executor import cancel_unless_interrupted, shutdown_pool, worker_context


def read_patch(image: np.ndarray, no_contact: np.ndarray, fit: photometric.LightFit | None,
               model: PatchModel) -> ContactPatch:
    """One image's contact patch: image (320, 240, 3) uint8 RGB, brought to its no-contact image's light and
    level by ``fit`` as ``align_images`` did (``photometric.apply_fit``; None: read as given), then read against
    no_contact (320, 240, 3)."""
    if fit is not None:
        image = photometric.apply_fit(image, fit)
    return image_to_patch(image, no_contact, model)


def _ready() -> bool:
    """A worker's first task: nothing, once it has imported the reading code."""
    return True


def started_pool(processes: int) -> concurrent.futures.ProcessPoolExecutor:
    """A spawn pool of ``processes`` workers (``worker_context``), returned once one of them has started: a
    worker that dies while starting is an error here, before any image is queued. (A spawn worker imports the
    caller's script again; without an ``if __name__ == "__main__":`` guard the script starts another pool
    there and the worker dies. Its pool is then broken, but with images queued behind it Python 3.11's pool
    can wait forever on the pipe the dead worker should have emptied.)"""
    pool = concurrent.futures.ProcessPoolExecutor(processes, mp_context=worker_context())
    try:
        pool.submit(_ready).result()
    except concurrent.futures.process.BrokenProcessPool as exc:
        shutdown_pool(pool)
        raise RuntimeError("the contact patches' worker processes died while starting: a script that tracks a "
                           "stream (Tracker.track) must keep its top-level code under `if __name__ == "
                           "\"__main__\":`, since each worker imports the script again (or set "
                           "track.read_ahead=0 to read the patches in this process)") from exc
    except BaseException:
        shutdown_pool(pool)
        raise
    return pool


class PatchReader:
    """``processes`` worker processes that read contact patches; a context manager (``close``).

    The pool starts with the first images submitted (each worker imports the reading code: about a second, which
    the first submission waits for, ``started_pool``) and is reused until ``close``; one reader may serve several
    trackers in turn.
    """

    def __init__(self, processes: int):
        if isinstance(processes, bool) or not isinstance(processes, int) or processes < 1:
            raise ConfigError(f"a patch reader needs a whole number of processes >= 1, got {processes!r}")
        self.processes = processes
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None

    def submit(self, images: np.ndarray, no_contacts: Sequence[np.ndarray],
               fits: Sequence[photometric.LightFit | None], model: PatchModel) -> list[concurrent.futures.Future]:
        """Start reading images (L, 320, 240, 3) uint8 RGB, each against its no-contact image and under its
        light fit (``read_patch``) -> L futures of ``ContactPatch``, in sensor order."""
        if not len(images) == len(no_contacts) == len(fits):
            raise ValueError(f"{len(images)} images, {len(no_contacts)} no-contact images and {len(fits)} light fits")
        if self._pool is None:
            self._pool = started_pool(self.processes)
        return [self._pool.submit(read_patch, image, nc, fit, model)
                for image, nc, fit in zip(images, no_contacts, fits)]

    @staticmethod
    def results(futures: Sequence[concurrent.futures.Future]) -> list[ContactPatch]:
        """The patches of ``submit``'s futures, waited for in order; a worker's error is raised here (the
        other futures are then cancelled)."""
        try:
            return [f.result() for f in futures]
        except BaseException:
            cancel_unless_interrupted(futures)
            raise

    def close(self) -> None:
        if self._pool is not None:
            pool, self._pool = self._pool, None
            shutdown_pool(pool)

    def __enter__(self) -> PatchReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
