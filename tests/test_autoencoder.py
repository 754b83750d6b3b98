from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from tactile6d.core.errors import ArtifactError, ConfigError, InputError
from tactile6d.perception import autoencoder as ae

CONF = Path(__file__).resolve().parent.parent / "conf" / "ae"


def small_cfg(**over):
    """A tiny model on 32x24 inputs, fast enough for unit tests; reconstruction loss only unless asked (the
    blob images have no contact types)."""
    cfg = dict(OmegaConf.to_container(OmegaConf.load(CONF / "cpu.yaml")))
    cfg.update(input_height=32, input_width=24, channels=[4, 8, 8, 16], epochs=2, batch_size=16, threads=1,
               rank_weight=0.0)
    cfg.update(over)
    return cfg


def background(rows=320, cols=240):
    """A smooth coloured gradient, like a DIGIT's no-contact image."""
    r, c = np.mgrid[0:rows, 0:cols]
    bg = np.stack([90 + 40 * r / rows, 110 + 30 * c / cols, 130 - 20 * r / rows], axis=-1)
    return bg.astype(np.uint8)


def blob_images(n, rng, bg):
    """Background plus one random coloured Gaussian blob per image, plus pixel noise (uint8)."""
    rows, cols = bg.shape[:2]
    r, c = np.mgrid[0:rows, 0:cols]
    out = np.empty((n, rows, cols, 3), dtype=np.uint8)
    for i in range(n):
        cr, cc = rng.uniform(0.2, 0.8) * rows, rng.uniform(0.2, 0.8) * cols
        sr, sc = rng.uniform(0.05, 0.2) * rows, rng.uniform(0.05, 0.2) * cols
        blob = np.exp(-0.5 * (((r - cr) / sr) ** 2 + ((c - cc) / sc) ** 2))
        colour = rng.uniform(-60, 60, size=3)
        img = bg + blob[..., None] * colour + rng.normal(0, 3, size=bg.shape)
        out[i] = np.clip(img, 0, 255)
    return out


@pytest.fixture(scope="module")
def small_set():
    bg = background(64, 48)
    return bg, blob_images(64, np.random.default_rng(0), bg)


def test_cpu_preset_shapes():
    cfg = OmegaConf.load(CONF / "cpu.yaml")
    model = ae.build_model(cfg)
    x = torch.zeros(2, 3, cfg.input_height, cfg.input_width)
    h = model.encode(x)
    assert h.shape == (2, 128)
    assert model.decode(h).shape == x.shape


@pytest.mark.slow
def test_paper_preset_shapes():
    cfg = OmegaConf.load(CONF / "paper.yaml")
    model = ae.build_model(cfg)
    assert (cfg.input_height, cfg.input_width) == (320, 240)
    with torch.no_grad():
        x = torch.zeros(1, 3, 320, 240)
        h = model.encode(x)
        assert h.shape == (1, 128)
        assert model.decode(h).shape == x.shape
    assert [conv.out_channels for conv in model.encoder_convs] == [128, 256, 256, 512]


def test_odd_sizes_round_trip():
    model = ae.build_model(small_cfg(input_height=45, input_width=37))
    x = torch.zeros(3, 3, 45, 37)
    assert model(x).shape == x.shape


def test_preprocess_maps_background_to_zero_and_averages_blocks():
    bg = background()
    imgs = np.stack([bg, np.clip(bg.astype(int) + 8, 0, 255).astype(np.uint8)])
    norm = ae.Normalisation(height=80, width=60, scale=(2.0, 4.0, 8.0), peak_floor=None, offset=0.0)
    x = ae.preprocess(imgs, bg, norm)
    assert x.shape == (2, 3, 80, 60) and x.dtype == torch.float32
    assert torch.all(x[0] == 0)
    diff = (imgs[1].astype(np.float64) - bg)[:4, :4].mean(axis=(0, 1))
    np.testing.assert_allclose(x[1, :, 0, 0].numpy(), diff / np.array([2.0, 4.0, 8.0]), rtol=1e-6)


@pytest.mark.parametrize("per_image", [False, True])
def test_resized_difference_in_chunks_equals_the_whole_batch_at_once(per_image):
    """The buffered, chunked differences give the bits of one whole-batch interpolation (the formula used
    before the buffer), and agree with a naive float64 block mean."""
    rng = np.random.default_rng(3)
    bg = background(40, 30)
    n = 2 * ae._DIFFERENCE_CHUNK + 3  # two full chunks and a partial one
    imgs = blob_images(n, rng, bg)
    bgs = blob_images(n, rng, bg) if per_image else bg
    got = ae._resized_difference(imgs, bgs, 8, 6)
    whole = torch.from_numpy(imgs.astype(np.float32) - np.asarray(bgs, dtype=np.float32)).permute(0, 3, 1, 2)
    assert torch.equal(got, torch.nn.functional.interpolate(whole, size=(8, 6), mode="area").contiguous())
    naive = (imgs.astype(np.float64) - bgs).reshape(n, 8, 5, 6, 5, 3).mean(axis=(2, 4)).transpose(0, 3, 1, 2)
    np.testing.assert_allclose(got.numpy(), naive, rtol=1e-6, atol=1e-4)


@pytest.mark.slow
def test_peak_normalisation_removes_the_press_depth_but_not_the_noise_floor():
    diffs = torch.zeros(3, 3, 8, 6)
    diffs[0, :, 2:4, 2:4] = 10.0          # colour-summed peak 30
    diffs[1] = 2.0 * diffs[0]             # the same imprint pressed twice as hard
    diffs[2, 0, 0, 0] = 4.0               # sensor noise only: peak 4, below the floor
    out = ae.divide_by_peak(diffs, 20.0)
    torch.testing.assert_close(out[0], out[1])
    assert float(out[0].abs().sum(dim=0).max()) == pytest.approx(1.0)
    assert float(out[2].abs().max()) == pytest.approx(4.0 / 20.0)
    assert ae.divide_by_peak(diffs, None) is diffs


def test_preprocess_with_peak_floor_gives_unit_peaks():
    bg = background()
    pressed = bg.astype(int)
    pressed[100:140, 80:120] += 40
    imgs = np.stack([bg, np.clip(pressed, 0, 255).astype(np.uint8)])
    x = ae.preprocess(imgs, bg, ae.Normalisation(height=64, width=48, scale=(1.0, 1.0, 1.0), peak_floor=20.0, offset=0.0))
    assert torch.all(x[0] == 0)
    assert float(x[1].abs().sum(dim=0).max()) == pytest.approx(1.0, rel=1e-5)


def test_normalisation_dict_round_trip_and_incomplete_ones_refused():
    norm = ae.Normalisation(32, 24, (1.0, 2.0, 3.0), peak_floor=20.0, offset=0.5)
    assert ae.Normalisation.from_dict(norm.to_dict()) == norm
    with pytest.raises(KeyError, match="offset"):
        ae.Normalisation.from_dict({"height": 32, "width": 24, "scale": [1, 2, 3], "peak_floor": None})
    with pytest.raises(ValueError, match="peak_floor"):
        ae.Normalisation.from_dict({**norm.to_dict(), "peak_floor": 0.0})


@pytest.mark.parametrize("key, value", [
    ("input_offset", float("nan")), ("peak_floor", 0.0), ("bootstrap_fraction", 0.0), ("kernel_size", 4),
    ("device", "tpu"), ("rank_weight", -1.0), ("rank_margin", float("inf")),
])
def test_bad_ae_settings_are_config_errors_naming_the_key(key, value):
    with pytest.raises(ConfigError, match=f"ae.{key}"):
        ae.AEConfig.from_cfg(small_cfg(**{key: value}))


@pytest.mark.parametrize("key", ["rank_weight", "peak_floor", "input_offset"])
def test_every_ae_setting_comes_from_the_config(key):
    cfg = small_cfg()
    del cfg[key]
    with pytest.raises(ConfigError, match=f"ae config lacks keys \\['{key}'\\]"):
        ae.AEConfig.from_cfg(cfg)


def test_bootstrapped_l2_is_mean_of_largest_quarter():
    target = torch.zeros(1, 3, 2, 4)
    recon = torch.zeros(1, 3, 2, 4)
    recon[0, 0, 0, :] = torch.tensor([1.0, 2.0, 3.0, 4.0])  # per-pixel errors 1, 4, 9, 16, then zeros
    assert float(ae.bootstrapped_l2(recon, target, 0.25)) == pytest.approx((16 + 9) / 2)
    assert float(ae.bootstrapped_l2(recon, target, 1.0)) == pytest.approx(30 / 8)


@pytest.mark.slow
def test_training_reduces_the_loss(small_set):
    bg, imgs = small_set
    cfg = small_cfg(epochs=8, batch_size=8, channels=[8, 16, 16, 32])
    _model, norm, hist = ae.train(imgs, bg, cfg, seed=0, progress=False)
    assert len(hist["train_loss"]) == len(hist["val_loss"]) == len(hist["seconds"]) == 8
    assert hist["train_loss"][-1] < 0.9 * hist["train_loss"][0]
    assert min(hist["val_loss"]) < hist["val_loss"][0]
    assert hist["n_train"] + hist["n_val"] == len(imgs) and hist["n_val"] == 6
    assert all(s > 0 for s in norm.scale)


def test_same_seed_same_weights_and_global_state_restored(small_set):
    bg, imgs = small_set
    threads = torch.get_num_threads()
    m1, n1, _ = ae.train(imgs[:24], bg, small_cfg(epochs=1), seed=3, progress=False)
    m2, n2, _ = ae.train(imgs[:24], bg, small_cfg(epochs=1), seed=3, progress=False)
    m3, _, _ = ae.train(imgs[:24], bg, small_cfg(epochs=1), seed=4, progress=False)
    assert n1 == n2
    for (k, a), b in zip(m1.state_dict().items(), m2.state_dict().values()):
        assert torch.equal(a, b), k
    assert not torch.equal(m1.to_latent.weight, m3.to_latent.weight)
    assert torch.get_num_threads() == threads
    assert not torch.are_deterministic_algorithms_enabled()


@pytest.mark.slow
def test_encode_is_deterministic_and_background_is_its_own_reference(small_set):
    bg, imgs = small_set
    torch.manual_seed(0)
    model = ae.build_model(small_cfg())
    norm = ae.Normalisation(32, 24, (5.0, 5.0, 5.0), None, 0.0)
    h1 = ae.encode(model, norm, imgs, bg, batch_size=16)
    h2 = ae.encode(model, norm, imgs, bg, batch_size=16)
    assert h1.shape == (len(imgs), 128) and h1.dtype == np.float32
    assert np.array_equal(h1, h2)
    h_nc = ae.encode(model, norm, bg[None], bg)[0]
    assert ae.latent_angles(h_nc[None], h_nc)[0] == pytest.approx(0.0, abs=1e-6)


def test_latent_angles_match_a_naive_reference():
    rng = np.random.default_rng(1)
    h = rng.normal(size=(20, 128)).astype(np.float32)
    h_nc = rng.normal(size=128).astype(np.float32)
    expected = [
        np.arccos(min(1.0, max(-1.0, float(np.dot(v, h_nc)) / (np.linalg.norm(v) * np.linalg.norm(h_nc)))))
        for v in h.astype(np.float64)
    ]
    np.testing.assert_allclose(ae.latent_angles(h, h_nc), expected, atol=1e-12)
    assert ae.latent_angles(h_nc[None], -h_nc)[0] == pytest.approx(np.pi)
    assert ae.latent_angles(np.zeros((1, 128)), h_nc)[0] == pytest.approx(np.pi / 2)


def test_training_with_a_peak_floor_and_offset_keeps_them_in_the_normalisation(tmp_path, small_set):
    bg, imgs = small_set
    cfg = small_cfg(epochs=1, peak_floor=20.0, input_offset=0.5)
    model, norm, _ = ae.train(imgs[:24], bg, cfg, seed=0, progress=False)
    assert norm.peak_floor == 20.0 and norm.offset == 0.5
    ae.save_checkpoint(tmp_path / "ae.pt", model, norm, cfg, {})
    _, norm2, cfg2 = ae.load_checkpoint(tmp_path / "ae.pt")
    assert norm2 == norm and cfg2["peak_floor"] == 20.0 and cfg2["input_offset"] == 0.5
    # The scale is the RMS of the offset input, so the constant dominates it: about 0.5 per channel.
    assert all(0.4 < s < 0.6 for s in norm.scale)


def test_the_offset_turns_the_no_contact_image_into_a_uniform_nonzero_input():
    bg = background()
    pressed = bg.astype(int)
    pressed[100:140, 80:120] += 40
    imgs = np.stack([bg, np.clip(pressed, 0, 255).astype(np.uint8)])
    norm = ae.Normalisation(height=64, width=48, scale=(0.5, 0.5, 0.5), peak_floor=20.0, offset=0.5)
    x = ae.preprocess(imgs, bg, norm)
    assert torch.all(x[0] == 1.0)
    contact = x[1] - x[0]
    assert float(contact.abs().sum(dim=0).max()) == pytest.approx(2.0, rel=1e-5)  # unit peak / scale 0.5


@pytest.mark.slow
def test_checkpoint_round_trip(tmp_path, small_set):
    bg, imgs = small_set
    cfg = small_cfg()
    torch.manual_seed(0)
    model = ae.build_model(cfg)
    norm = ae.Normalisation(32, 24, (1.5, 2.5, 3.5), None, 0.0)
    path = tmp_path / "sub" / "ae.pt"
    # NumPy values in the history must not make the checkpoint unloadable with weights_only=True
    ae.save_checkpoint(path, model, norm, cfg, {"train_loss": np.array([1.0, 0.5]), "seconds": [np.float64(2)]})
    assert [p.name for p in path.parent.iterdir()] == ["ae.pt"]  # no temporary file left behind
    model2, norm2, cfg2 = ae.load_checkpoint(path)
    assert norm2 == norm and cfg2["channels"] == (4, 8, 8, 16)
    np.testing.assert_array_equal(ae.encode(model, norm, imgs, bg), ae.encode(model2, norm2, imgs, bg))


def _expect_artifact_error(path, fragment):
    with pytest.raises(ArtifactError) as err:
        ae.load_checkpoint(path)
    msg = str(err.value)
    assert str(path) in msg and fragment in msg and "dvc repro train_ae" in msg and "\n" not in msg


def test_bad_checkpoints_raise_artifact_errors(tmp_path):
    cfg = small_cfg()
    model = ae.build_model(cfg)
    norm = ae.Normalisation(32, 24, (1.0, 1.0, 1.0), None, 0.0)

    _expect_artifact_error(tmp_path / "absent.pt", "missing")

    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(np.random.default_rng(0).bytes(1000))
    _expect_artifact_error(garbage, "not a readable torch checkpoint")

    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    _expect_artifact_error(foreign, "not a tactile6d-autoencoder")

    partial = tmp_path / "partial.pt"
    torch.save({"format": ae.CHECKPOINT_FORMAT, "state_dict": model.state_dict()}, partial)
    _expect_artifact_error(partial, "lacks keys ['norm', 'cfg', 'history']")

    wrong_shape = tmp_path / "wrong_shape.pt"
    ae.save_checkpoint(wrong_shape, model, norm, cfg, {})
    payload = torch.load(wrong_shape, weights_only=True)
    payload["cfg"]["channels"] = (4, 8, 8, 32)
    torch.save(payload, wrong_shape)
    _expect_artifact_error(wrong_shape, "weights do not fit its config")


def test_angle_ranking_loss_matches_a_naive_pair_loop():
    rng = np.random.default_rng(2)
    cos = torch.from_numpy(rng.uniform(-1, 1, size=12))
    sharp = torch.from_numpy(rng.integers(-1, 3, size=12))
    terms = [max(0.0, 0.3 - (float(cos[i]) - float(cos[j])))
             for i in range(12) for j in range(12) if sharp[i] > sharp[j] >= 0]
    assert terms  # the draw has ordered pairs
    assert float(ae.angle_ranking_loss(cos, sharp, 0.3)) == pytest.approx(np.mean(terms), rel=1e-12)
    # A correctly ordered batch with room to spare costs nothing; unranked or single-rank batches too.
    assert float(ae.angle_ranking_loss(torch.tensor([0.9, 0.5, 0.1]), torch.tensor([2, 1, 0]), 0.3)) == 0.0
    assert float(ae.angle_ranking_loss(cos, torch.full((12,), -1), 0.3)) == 0.0
    assert float(ae.angle_ranking_loss(cos, torch.ones(12, dtype=torch.int64), 0.3)) == 0.0


@pytest.mark.slow
def test_the_ranking_term_puts_sharp_contacts_closer_to_no_contact(small_set):
    """Label the small blobs sharp and the large ones flat: with the ranking term the small blobs' angles
    end up below the large ones' on the training images."""
    bg, imgs = small_set
    area = (np.abs(imgs.astype(int) - bg.astype(int)).sum(-1) > 30).sum(axis=(1, 2))
    sharp = np.where(area < np.median(area), 2, 0)
    cfg = small_cfg(epochs=6, batch_size=8, rank_weight=5.0, rank_margin=0.2, val_fraction=0.0)
    model, norm, hist = ae.train(imgs, bg, cfg, seed=0, progress=False, sharpness=sharp, no_contact=bg)
    assert len(hist["rank_loss"]) == 6 and hist["rank_loss"][-1] < hist["rank_loss"][0]
    angles = ae.latent_angles(ae.encode(model, norm, imgs, bg), ae.encode(model, norm, bg[None], bg)[0])
    assert np.median(angles[sharp == 2]) < np.median(angles[sharp == 0])
    with pytest.raises(InputError, match="sharpness"):
        ae.train(imgs, bg, cfg, seed=0, progress=False)
    with pytest.raises(InputError, match=r"shape \(64,\)"):
        ae.train(imgs, bg, cfg, seed=0, progress=False, sharpness=sharp[:10], no_contact=bg)
