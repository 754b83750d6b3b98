import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tactile6d.errors import ArtifactError
from tactile6d.io import read_artifact, write_artifact


def surface_data(n=10):
    rng = np.random.default_rng(0)
    return {"points": rng.normal(size=(n, 3)), "normals": rng.normal(size=(n, 3)), "face_index": np.arange(n)}


def test_round_trip_keeps_data_stamp_and_config(tmp_path):
    path = write_artifact(tmp_path / "s.h5", "surface", surface_data(), attrs={"object": "x"}, config={"sample": {"M": 10}})
    art = read_artifact(path, "surface")
    np.testing.assert_array_equal(art["points"], surface_data()["points"])
    assert art.config == {"sample": {"M": 10}}
    assert art.attrs["object"] == "x"
    assert [p.name for p in tmp_path.iterdir()] == ["s.h5"]  # no temporary file left


def test_missing_artifact_names_the_stage(tmp_path):
    with pytest.raises(ArtifactError, match=r"missing.*sample_surface.*dvc repro sample_surface"):
        read_artifact(tmp_path / "nope.h5", "surface")


def test_corrupt_artifact_gives_a_clear_error(tmp_path):
    path = write_artifact(tmp_path / "s.h5", "surface", surface_data())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])  # truncated, as by a disk-full copy
    with pytest.raises(ArtifactError, match=r"s\.h5: unreadable or corrupt HDF5.*sample_surface"):
        read_artifact(path, "surface")
    path.write_bytes(b"not hdf5 at all")
    with pytest.raises(ArtifactError, match="unreadable or corrupt"):
        read_artifact(path, "surface")


def test_wrong_schema_is_named(tmp_path):
    path = write_artifact(tmp_path / "s.h5", "surface", surface_data())
    with pytest.raises(ArtifactError, match=r"schema is 'surface' but 'object' was expected.*prepare_object"):
        read_artifact(path, "object")


def test_writer_refuses_incomplete_data(tmp_path):
    with pytest.raises(ValueError, match="lacks datasets"):
        write_artifact(tmp_path / "s.h5", "surface", {"points": np.zeros((1, 3))})
    assert not list(tmp_path.iterdir())


def test_interrupted_write_leaves_no_file(tmp_path):
    """Kill a writer in the middle of a large write: neither the artifact nor a temp file remains."""
    target = tmp_path / "big.h5"
    script = textwrap.dedent(f"""
        import numpy as np, sys
        import tactile6d.io as io
        class Slow(dict):
            pass
        big = np.zeros((4000, 1000, 3))
        data = {{"points": big, "normals": big, "face_index": np.arange(4000)}}
        orig = io.h5py.File.create_dataset if hasattr(io.h5py.File, "create_dataset") else None
        import h5py
        real = h5py.Group.create_dataset
        def slow(self, *a, **k):
            print("writing", flush=True)
            import time; time.sleep(30)
            return real(self, *a, **k)
        h5py.Group.create_dataset = slow
        io.write_artifact({str(target)!r}, "surface", data)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                            cwd=os.path.dirname(os.path.dirname(__file__)))
    assert proc.stdout.readline().strip() == "writing"
    assert list(tmp_path.iterdir())  # the temporary file exists while writing
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # SIGKILL gives no chance to clean up: the temp file may remain, but never the artifact itself.
    assert not target.exists()
    assert all(".tmp-" in p.name for p in tmp_path.iterdir())


def test_exception_during_write_cleans_up(tmp_path, monkeypatch):
    import h5py

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(h5py.Group, "create_dataset", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        write_artifact(tmp_path / "s.h5", "surface", surface_data())
    assert not list(tmp_path.iterdir())
