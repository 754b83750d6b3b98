"""Stages train_ae and encode_database, tiny and end to end: training set -> model -> database latents."""

import json

import numpy as np
import pytest

from stages import encode_database, make_training_set, prepare_object, render_database, sample_surface, train_ae
from tactile6d import autoencoder, layout
from tactile6d.errors import ArtifactError
from tactile6d.io import read_artifact


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory, data_dir):
    root = tmp_path_factory.mktemp("artifacts")
    common = [f"paths.artifacts_dir={root}", f"paths.data_dir={data_dir}", "render.workers=1"]
    assert make_training_set.main([*common, "training_set.n_images=24", "training_set.n_shapes=3"]) == 0
    ae = ["ae.epochs=2", "ae.input_height=32", "ae.input_width=24", "ae.channels=[4,8,8,16]", "ae.batch_size=8"]
    assert train_ae.main([*common, *ae]) == 0
    assert prepare_object.main(["--object", "prim_box", *common, "prepare.collision=hull"]) == 0
    assert sample_surface.main(["--object", "prim_box", *common, "sample.M=16"]) == 0
    assert render_database.main(["--object", "prim_box", *common]) == 0
    assert encode_database.main(["--object", "prim_box", *common]) == 0
    return root


def test_training_writes_a_loadable_checkpoint_and_a_curve(artifacts):
    model, norm, cfg = autoencoder.load_checkpoint(layout.ae_checkpoint(artifacts))
    assert (norm.height, norm.width) == (32, 24) and cfg["epochs"] == 2
    curve = (layout.ae_dir(artifacts) / "training_curve.csv").read_text().splitlines()
    assert curve[0] == "epoch,train_loss,val_loss" and len(curve) == 3
    summary = json.loads((layout.ae_dir(artifacts) / "train.json").read_text())
    assert summary["train_seconds"] > 0 and summary["n_train"] + summary["n_val"] == 24


def test_latents_match_a_direct_encoding(artifacts):
    from tactile6d.database import StoredImages

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
