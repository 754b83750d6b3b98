"""Stages prepare_object and sample_surface: the object file is the same bytes wherever the data directory
lies; the worker count of their --distractors run is checked."""

import shutil

import pytest

from stages import prepare_object
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact


@pytest.mark.slow
def test_the_object_file_does_not_depend_on_where_the_data_directory_lies(tmp_path, data_dir):
    # A CI machine that keeps the data under another path once wrote other bytes than dvc.lock's md5,
    # because the object recorded the mesh's absolute path.
    elsewhere = tmp_path / "elsewhere" / "data"  # a copy (a link would resolve to the same path)
    shutil.copytree(data_dir / "ycb" / "036_wood_block", elsewhere / "ycb" / "036_wood_block")
    made = []
    for i, data in enumerate([data_dir, elsewhere]):
        artifacts = tmp_path / f"artifacts{i}"
        argv = ["--object", "036_wood_block", f"paths.artifacts_dir={artifacts}", f"paths.data_dir={data}",
                "prepare.collision=hull"]
        assert prepare_object.main(argv) == 0
        made.append(layout.object_file(artifacts, "036_wood_block"))
    assert read_artifact(made[0], "object").attrs["source"] == "data directory: ycb/036_wood_block/textured_simple.obj"
    assert made[0].read_bytes() == made[1].read_bytes()


@pytest.mark.parametrize("stage, key", [("prepare_object", "prepare.workers"), ("sample_surface", "sample.workers")])
def test_a_worker_count_below_one_is_named(stage, key, tmp_path):
    import importlib

    from tactile6d.core.errors import ConfigError

    main = importlib.import_module(f"stages.{stage}").main
    with pytest.raises(ConfigError, match=f"{key} must be >= 1, got 0"):
        main(["--object", "prim_box", f"paths.artifacts_dir={tmp_path}", f"{key}=0"])
