"""Run in a subprocess by tests/test_interrupt.py, in its own process group, to be interrupted there.

``python tests/interrupt_child.py map DIR sleep|busy``: 6 tasks of 30 s (asleep, or a busy loop) over 2
local worker processes (``LocalExecutor``), each task first creating ``DIR/pid-<its process>``; then,
never reached, ``DIR/out.json`` written atomically.
``python tests/interrupt_child.py write DIR``: an artifact written atomically to ``DIR/artifact.h5``, each
dataset slowed to 30 s; ``DIR/writing`` is created when the first one starts.
``python tests/interrupt_child.py render DIR``: ``DigitRenderer.render_many`` of 4000 poses on a cube over
2 worker processes (tens of seconds); ``DIR/rendering`` is created first.
``python tests/interrupt_child.py read DIR``: a frame's three contact patches read over and over by a
``PatchReader`` of 2 worker processes, as ``Tracker.track`` reads them; ``DIR/reading`` is created first.
All run under ``exit_on_error``, as a stage does.
"""

import os
import signal
import sys
import time
from pathlib import Path

# Ctrl-C raises KeyboardInterrupt, as in a program a terminal runs in the foreground. A test run that a
# shell started in the background without job control (as CI may be) hands its children SIGINT ignored,
# and Python keeps an inherited "ignore": then nothing here would see the interrupt under test.
signal.signal(signal.SIGINT, signal.default_int_handler)

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent)]

import numpy as np  # noqa: E402 (after the path)

from tactile6d.core.errors import exit_on_error  # noqa: E402
from tactile6d.data.hdf5 import write_artifact, write_json  # noqa: E402
from tactile6d.runtime.executor import LocalExecutor  # noqa: E402

TASK_S = 30.0


def slow_task(directory: str, i: int, kind: str) -> int:
    """One task: say which process runs it, then take TASK_S seconds, asleep or busy (Python bytecode)."""
    Path(directory, f"pid-{os.getpid()}").touch()
    if kind == "sleep":
        time.sleep(TASK_S)
    else:
        end = time.monotonic() + TASK_S
        while time.monotonic() < end:
            pass
    return i


def map_tasks(directory: str, kind: str) -> int:
    with LocalExecutor(2) as executor:
        results = executor.map(slow_task, [directory] * 6, range(6), [kind] * 6)
    write_json(Path(directory) / "out.json", results)
    return 0


def write_slowly(directory: str) -> int:
    import h5py

    real = h5py.Group.create_dataset

    def slow(self, *args, **kwargs):
        Path(directory, "writing").touch()
        time.sleep(TASK_S)
        return real(self, *args, **kwargs)

    h5py.Group.create_dataset = slow
    big = np.zeros((4000, 3))
    write_artifact(Path(directory) / "artifact.h5", "surface",
                   {"points": big, "normals": big, "face_index": np.arange(4000)})
    return 0


def render_many(directory: str) -> int:
    import trimesh

    from tactile6d.core import sensor
    from tactile6d.sim.render import DigitRenderer

    background = np.full((sensor.IMAGE_HEIGHT, sensor.IMAGE_WIDTH, 3), 100, np.uint8)
    n = 4000
    T = sensor.sensor_poses_touching(np.tile([0.02, 0.0, 0.0], (n, 1)), np.tile([1.0, 0, 0], (n, 1)),
                                     np.linspace(0, 3, n), 0.0015)
    Path(directory, "rendering").touch()
    with DigitRenderer.from_default_config(background, workers=2) as renderer:
        renderer.render_many(trimesh.creation.box(extents=(0.04, 0.04, 0.04)), T, seeds=0)
    return 0


def read_patches(directory: str) -> int:
    from tactile6d.core import sensor
    from tactile6d.perception.contact_patch import PatchModel
    from tactile6d.perception.patch_reader import PatchReader

    rng = np.random.default_rng(0)
    no_contact = np.full((sensor.IMAGE_HEIGHT, sensor.IMAGE_WIDTH, 3), (120, 128, 124), np.uint8)
    images = np.clip(no_contact + rng.normal(0, 2, (3, *no_contact.shape)), 0, 255).astype(np.uint8)
    model = PatchModel(coefficients=np.zeros((56, 3)))  # never reached: these images show no contact
    Path(directory, "reading").touch()
    with PatchReader(2) as reader:
        while True:
            reader.results(reader.submit(images, [no_contact] * 3, [None] * 3, model))


if __name__ == "__main__":
    mode, directory = sys.argv[1], sys.argv[2]
    if mode == "map":
        sys.exit(exit_on_error(lambda: map_tasks(directory, sys.argv[3])))
    if mode == "render":
        sys.exit(exit_on_error(lambda: render_many(directory)))
    if mode == "read":
        sys.exit(exit_on_error(lambda: read_patches(directory)))
    sys.exit(exit_on_error(lambda: write_slowly(directory)))
