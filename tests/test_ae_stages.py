"""Stages train_ae, encode_database and ae_quality, tiny and end to end: training set -> model -> database
latents -> quality figures."""

import json

import numpy as np
import pytest

from stages import (
    encode_database,
    make_training_set,
    prepare_object,
    render_database,
    sample_surface,
    train_ae,
)
from tactile6d.core.errors import ArtifactError
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.perception import autoencoder

pytestmark = pytest.mark.slow  # end-to-end: excluded from the quick subset (-m 'not slow')


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory, data_dir):
    root = tmp_path_factory.mktemp("artifacts")
    common = [f"paths.artifacts_dir={root}", f"paths.data_dir={data_dir}", "render.workers=1"]
    assert make_training_set.main([*common, "training_set.n_images=24", "training_set.n_shapes=3"]) == 0
    ae = ["ae.epochs=2", "ae.input_height=32", "ae.input_width=24", "ae.channels=[4,8,8,16]", "ae.batch_size=8",
          "ae.rank_weight=1.0"]
    assert train_ae.main([*common, *ae]) == 0
    assert prepare_object.main(["--object", "prim_box", *common, "prepare.collision=hull"]) == 0
    assert sample_surface.main(["--object", "prim_box", *common, "sample.M=16"]) == 0
    assert render_database.main(["--object", "prim_box", *common]) == 0
    assert encode_database.main(["--object", "prim_box", *common]) == 0
    return root


def test_training_writes_a_loadable_checkpoint_and_a_curve(artifacts):
    _model, norm, cfg = autoencoder.load_checkpoint(layout.ae_checkpoint(artifacts))
    assert (norm.height, norm.width) == (32, 24) and cfg["epochs"] == 2
    curve = (layout.ae_dir(artifacts) / "training_curve.csv").read_text().splitlines()
    assert curve[0] == "epoch,train_loss,val_loss,rank_loss" and len(curve) == 3
    summary = json.loads((layout.ae_dir(artifacts) / "train.json").read_text())
    assert summary["train_seconds"] > 0 and summary["n_train"] + summary["n_val"] == 24
    assert summary["final_rank_loss"] >= 0.0


def test_ranking_on_a_training_set_without_contact_types_names_make_training_set(artifacts, tmp_path, data_dir):
    import h5py

    (tmp_path / "training_set.h5").write_bytes(layout.training_set_file(artifacts).read_bytes())
    with h5py.File(tmp_path / "training_set.h5", "a") as f:
        del f["contact_types"]  # as written before the classifier labelled the training set
    common = [f"paths.artifacts_dir={tmp_path}", f"paths.data_dir={data_dir}"]
    with pytest.raises(ArtifactError, match="make_training_set"):
        train_ae.main([*common, "ae.epochs=1", "ae.rank_weight=1.0"])


def test_latents_match_a_direct_encoding(artifacts):
    from tactile6d.sim.database import StoredImages

    lat = read_artifact(layout.latents_file(artifacts, "prim_box"), "latents")
    db = read_artifact(layout.database_file(artifacts, "prim_box"), "database")
    assert lat["latents"].shape == (16, 128) and lat["angles"].shape == (16,)
    model, norm, _ = autoencoder.load_checkpoint(layout.ae_checkpoint(artifacts))
    again = autoencoder.encode(model, norm, StoredImages(db), db["background"])
    np.testing.assert_array_equal(again, lat["latents"])  # encoding is deterministic
    np.testing.assert_allclose(lat["angles"], autoencoder.latent_angles(lat["latents"], lat["latent_nc"]))
    assert np.all((lat["angles"] >= 0) & (lat["angles"] <= np.pi))


def test_encoding_without_a_model_names_train_ae(artifacts, tmp_path, data_dir):
    common = [f"paths.artifacts_dir={tmp_path}", f"paths.data_dir={data_dir}"]
    (tmp_path / "databases").mkdir()
    (tmp_path / "databases" / "prim_box.h5").write_bytes(layout.database_file(artifacts, "prim_box").read_bytes())
    with pytest.raises(ArtifactError, match="train_ae"):
        encode_database.main(["--object", "prim_box", *common])


def test_quality_report_on_one_object(artifacts, data_dir):
    """ae_quality end to end: two rendered scenes of the box stand in for the paper's triplets."""
    import shutil

    from stages import ae_quality, make_scenes

    common = [f"paths.artifacts_dir={artifacts}", f"paths.data_dir={data_dir}", "objects.names=[prim_box]"]
    assert make_scenes.main(["--scene-set", "validation", *common, "scenes.validation.scenes_per_object=2"]) == 0
    shutil.copy(layout.scenes_file(artifacts, "validation"), layout.scenes_file(artifacts, "caddeo2023"))
    assert ae_quality.main(common) == 0
    figures = json.loads(layout.metrics_file(artifacts, "ae").read_text())
    assert sum(figures["count_by_type"].values()) == 16  # every database point has a contact type
    # With a single object every pair is a same-object pair: the within-object AUROCs are the pooled ones.
    for pair in ("flat_edge", "edge_corner"):
        assert figures[f"auroc_{pair}_within_object"] == pytest.approx(figures[f"auroc_{pair}"], nan_ok=True)
    assert 0.0 <= figures["triplet_angle_gap_median"] <= figures["triplet_angle_gap_p90"] <= np.pi
    assert (layout.ae_dir(artifacts) / "angles_by_type.png").stat().st_size > 0
