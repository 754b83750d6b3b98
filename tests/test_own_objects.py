"""Your own objects (config section ``own``): a mesh file that ships inside an installed package becomes a library
object through the per-object stages run with ``--own``, is estimated by name and identified among the library."""

import json
import re
from pathlib import Path

import numpy as np
import pybullet_data
import pytest
from omegaconf import OmegaConf
from test_estimator import write_tiny_autoencoder

from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, ConfigError
from tactile6d.data import layout
from tactile6d.sim.mesh_import import MeshSource, own_objects

BUNNY = Path(pybullet_data.getDataPath()) / "bunny.obj"  # about 2 x 1.4 x 1 file units: 10 cm as cm x 5
OWN = [f"+own.bunny.mesh={BUNNY}", "+own.bunny.units=cm", "+own.bunny.scale=5"]
# The weights stage calibrate_identify fitted in the run dvc.lock records (loss, penetration, agreement; 2026-12-06, the
# stages from rank on re-run for ff88cff).
WEIGHTS = "identify.weights=[3.4885,0.3917,8.6344]"


@pytest.mark.slow
def test_an_entry_is_checked_and_names_its_key():
    cfg = compose_config(OWN)
    assert own_objects(cfg)["bunny"] == MeshSource("bunny", BUNNY, "cm", 5.0, (0.0, 0.0, 0.0))
    # The default config's own objects: the packaged meshes the pipeline's own scene set measures (own_set).
    assert set(own_objects(compose_config())) == set(compose_config().own_set.files)
    for entry, message in (({"mesh": "a.stl"}, r"own.part.units is missing"),
                           ({"mesh": "a.stl", "units": "furlong"}, r"own.part.units: 'furlong' unknown"),
                           ({"mesh": "a.stl", "units": "mm", "scale": -1}, r"own.part.scale must be a positive"),
                           ({"mesh": "a.stl", "units": "mm", "offset": [0, 1]}, r"own.part.offset must be three"),
                           ({"mesh": "a.stl", "units": "mm", "colour": "red"}, r"own.part: unknown key colour")):
        with pytest.raises(ConfigError, match=message):
            MeshSource.from_config("part", entry)
    with pytest.raises(ConfigError, match="may hold letters"):
        MeshSource.from_config("my part", {"mesh": "a.stl", "units": "mm"})


def make_library(root: Path) -> None:
    """The bunny (own, 2000 database points as the pipeline's default) and two primitives, each through the
    per-object stages' main(), with one tiny untrained autoencoder for all."""
    from stages import encode_database, prepare_object, render_database, sample_surface

    write_tiny_autoencoder(root, 10, "unused")
    for name, flags, points in (("bunny", ["--own", *OWN], 2000), ("prim_box", [], 500), ("prim_cylinder", [], 500)):
        common = ["--object", name, *flags, f"paths.artifacts_dir={root}"]
        assert prepare_object.main(common + ["prepare.collision=hull", "prepare.n_metric_points=300"]) == 0
        assert sample_surface.main(common + [f"sample.M={points}"]) == 0
        assert render_database.main(common) == 0
        assert encode_database.main(common) == 0


@pytest.mark.slow
def test_a_packaged_mesh_is_estimated_within_a_centimetre_and_identified(tmp_path, data_dir, monkeypatch):
    from stages import make_scenes
    from tactile6d.cli.objects import KnownObjects
    from tactile6d.data.hdf5 import read_artifact
    from tactile6d.data.third_party import DataStore
    from tactile6d.estimation.estimator import Estimator
    from tactile6d.estimation.identifier import Identifier

    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    root = tmp_path / "artifacts"
    make_library(root)
    own_dir = layout.own_dir(root)
    assert (own_dir / "objects" / "bunny.h5").is_file() and not (root / "objects" / "bunny.h5").exists()
    obj = read_artifact(layout.object_file(own_dir, "bunny"), "object")
    assert obj.attrs["source"] == f"mesh file: {BUNNY} (cm)"
    assert 0.09 < float(np.max(np.ptp(obj["vertices"], axis=0))) < 0.11  # 10 cm: 2 file units x 1 cm x 5

    # The tiny autoencoder's angles mean nothing: the delta_h thresholds wide open, and the identification's
    # screen as wide as the full estimate (its few tuples are picked by those angles otherwise).
    cfg = compose_config([f"paths.artifacts_dir={root}", *OWN, "scenes.validation.scenes_per_object=3",
                          "select.delta_h=3.2", "select.delta_h_max=3.2", WEIGHTS, "identify.workers=1",
                          "identify.screen.N=5000", "identify.screen.candidates=30"])
    scenes = make_scenes.generate("validation", ["bunny"], cfg, DataStore(cfg.paths), str(own_dir))  # the renderer's

    known = KnownObjects(root, cfg)
    bunny = known.require_artifacts("bunny")
    assert bunny.kind == "own" and bunny.objects_dir == own_dir
    estimator = Estimator.from_artifacts("bunny", root, cfg, objects_dir=bunny.objects_dir)
    errors = [np.linalg.norm(estimator.estimate(scenes.T_world_sensors[s], scenes.images[s]).best[:3, 3]
                             - scenes.T_world_object[s][:3, 3]) for s in range(len(scenes.names))]
    assert max(errors) < 0.01, errors

    with Identifier.from_artifacts(["prim_box", "prim_cylinder"], root, cfg, own=["bunny"]) as identifier:
        for s in range(len(scenes.names)):
            assert identifier.identify(scenes.T_world_sensors[s], scenes.images[s]).best.name == "bunny"

    # The pipeline's own scene set and its evaluation, on the bunny alone among the same library.
    from stages import evaluate_own

    own_set = [f"paths.artifacts_dir={root}", *OWN, "~own_set.files", "+own_set.files={bunny: bunny.obj}",
               "own_set.scenes.scenes_per_object=2", "objects.names=[prim_box,prim_cylinder]", "identify.distractors=[]",
               "select.delta_h=3.2", "select.delta_h_max=3.2", WEIGHTS, "identify.workers=1", "identify.screen.N=5000",
               "identify.screen.candidates=30"]
    assert make_scenes.main(["--scene-set", "own", *own_set]) == 0
    assert evaluate_own.main(own_set) == 0
    metrics = json.loads(layout.metrics_file(root, "own").read_text())
    assert metrics["n_scenes"] == 2 and metrics["meshes"]["bunny"]["faces"] == 902
    assert metrics["estimate"]["average"]["pos_err_cm_top1"] < 1.0 and metrics["estimate"]["n_failed"] == 0
    # Identified first in both scenes with the refinement of before 2026-12-06, in at least one of the two since (the
    # contact normals out of it, the patch points weighing 3: docs/contact_patch.md) with the weights calibrate_identify
    # fits for it (WEIGHTS; with those of the refinement before, in neither); the three validation scenes above are
    # identified right either way.
    assert metrics["identify"]["objects"] == ["prim_box", "prim_cylinder", "bunny"] and metrics["identify"]["top1"] >= 0.5


def test_missing_artifacts_of_an_own_object_name_its_own_stages(tmp_path):
    from tactile6d.cli.objects import KnownObjects

    known = KnownObjects(tmp_path, compose_config(OWN))
    assert known.get("bunny").kind == "own"
    with pytest.raises(ArtifactError, match=r"`dvc repro prepare_own@bunny sample_own@bunny encode_own@bunny`"):
        known.require_artifacts("bunny")
    assert re.search(r"your own objects \(conf/own\): [^;]*\bbunny\b", known.listing())


@pytest.mark.slow
def test_an_own_object_may_not_take_a_ycb_or_built_in_name(tmp_path, data_dir, monkeypatch):
    from stages import prepare_object

    monkeypatch.setenv("TACTILE6D_DATA", str(data_dir))
    for name in ("011_banana", "prim_box"):
        cfg = compose_config([f"paths.artifacts_dir={tmp_path}"])
        OmegaConf.set_struct(cfg, False)  # a key that starts with a digit has no Hydra override syntax
        cfg.own = {name: {"mesh": str(BUNNY), "units": "cm"}}
        with pytest.raises(ConfigError, match=f"own.{name}: the name is taken"):
            prepare_object.prepare_object(name, cfg, layout.own_dir(tmp_path))
