"""Stage render_database on a built-in box, the compact image storage, the body-contact flag, bench render."""

import json

import numpy as np
import pytest
import trimesh

from stages import prepare_object, render_database, sample_surface
from tactile6d.core import sensor
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, ConfigError, InputError
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.data.third_party import DataStore
from tactile6d.sim import database
from tactile6d.sim.render import DigitRenderer, load_background_bgr

M = 20
H, W = sensor.IMAGE_HEIGHT, sensor.IMAGE_WIDTH


@pytest.fixture(scope="module")
def overrides(tmp_path_factory, data_dir):
    artifacts = tmp_path_factory.mktemp("artifacts")
    # hull collision and few metric points keep prepare_object fast; one render process avoids the
    # workers' start-up (seconds) for 20 images
    return [f"paths.artifacts_dir={artifacts}", f"paths.data_dir={data_dir}", f"sample.M={M}", "prepare.collision=hull",
            "prepare.n_metric_points=50", "render.workers=1"]


@pytest.fixture(scope="module")
def built(overrides):
    """The box's object, surface and database artifacts, made by the three stages."""
    for stage in (prepare_object, sample_surface, render_database):
        assert stage.main(["--object", "prim_box", *overrides]) == 0
    cfg = compose_config(overrides)
    artifacts = cfg.paths.artifacts_dir
    return (
        cfg,
        read_artifact(layout.object_file(artifacts, "prim_box"), "object"),
        read_artifact(layout.surface_file(artifacts, "prim_box"), "surface"),
        read_artifact(layout.database_file(artifacts, "prim_box"), "database"),
    )


@pytest.mark.slow
def test_one_image_per_surface_point(built):
    _, _, surface, db = built
    assert database.image_count(db) == M
    np.testing.assert_array_equal(db["points"], surface["points"])
    assert db["T_object_sensor"].shape == (M, 4, 4)
    assert db["noise_seeds"].shape == (M,) and len(set(db["noise_seeds"].tolist())) == M
    assert db["background"].shape == (H, W, 3) and db["no_contact"].shape == (H, W, 3)
    assert database.database_images(db, slice(None)).shape == (M, H, W, 3)


def test_sensors_touch_their_points(built):
    cfg, _, surface, db = built
    T = db["T_object_sensor"]
    points, normals = surface["points"], surface["normals"]
    # the contact point lies 2 mm - depth outside the surface, along the normal; the sensor looks along -n
    gap = sensor.GEL_CENTER[0] - sensor.CONTACT_POINT[0] - cfg.render.press_depth
    np.testing.assert_allclose(sensor.contact_points(T), points + gap * normals, atol=1e-12)
    np.testing.assert_allclose(T[:, :3, 0], -normals, atol=1e-12)
    assert np.all(db["depths"] == cfg.render.press_depth)
    assert np.unique(np.round(db["rolls"], 6)).size == M  # roll rule "random": one per point


def test_rebuilt_images_equal_direct_renders(built):
    cfg, obj, _, db = built
    mesh = trimesh.Trimesh(obj["vertices"], obj["faces"], process=False)
    background = load_background_bgr(cfg, DataStore(cfg.paths))
    renderer = DigitRenderer.from_config(cfg.render, background, workers=1, strict=False)
    picks = [0, 7, M - 1]
    stored = database.database_images(db, picks)
    masks = database.database_masks(db, picks)
    for k, i in enumerate(picks):
        direct = renderer.render(mesh, np.eye(4), db["T_object_sensor"][i], seed=int(db["noise_seeds"][i]))
        np.testing.assert_array_equal(stored[k], direct.image)
        np.testing.assert_array_equal(masks[k], direct.mask)
    np.testing.assert_array_equal(db["background"], renderer.background.astype(np.uint8))
    lazy = database.StoredImages(db)
    assert lazy.shape == (M, H, W, 3) and len(lazy) == M
    np.testing.assert_array_equal(lazy[7], stored[1])
    np.testing.assert_array_equal(lazy[M - 1 :], stored[2:])


@pytest.mark.parametrize("threads", [2, 3])
def test_images_decoded_on_threads_equal_those_decoded_on_one(built, monkeypatch, threads):
    _, _, _, db = built
    picks = np.arange(4 * M) % M  # enough images for every thread to get some
    monkeypatch.setattr(database, "_DECODE_THREADS", 1)
    one = database.database_images(db, picks)
    monkeypatch.setattr(database, "_DECODE_THREADS", threads)
    np.testing.assert_array_equal(database.database_images(db, picks), one)
    np.testing.assert_array_equal(one[M:2 * M], one[:M])  # each image its own seed, wherever it falls


def test_masks_and_compression(built):
    _cfg, _, _, db = built
    assert np.mean(db["mask_pixels"] > 0) >= 0.9  # a box: every sensor presses on a face
    size = db.path.stat().st_size
    raw = M * H * W * 3
    assert size < raw / 4, (size, raw)  # measured: about 40 KB per image of a box face, raw is 230 KB
    assert not db["body_contact"].any()  # a convex object never reaches behind the gel


def test_a_corrupt_database_is_a_clear_artifact_error(built, tmp_path):
    _, _, _, db = built
    broken = tmp_path / "prim_box.h5"
    broken.write_bytes(db.path.read_bytes()[: db.path.stat().st_size // 2])
    with pytest.raises(ArtifactError, match="render_database"):
        read_artifact(broken, "database")
    with pytest.raises(ArtifactError, match="schema is 'surface' but 'database'"):
        read_artifact(layout.surface_file(built[0].paths.artifacts_dir, "prim_box"), "database")


def test_encoding_round_trips():
    rng = np.random.default_rng(0)
    small = rng.integers(-128, 128, size=(H, W, 3)).astype(np.int16)
    large = small * 2  # outside int8: stored as 16 bits
    for difference in (small, large, np.zeros((H, W, 3), np.int16)):
        blob = database.encode_difference(difference)
        np.testing.assert_array_equal(database.decode_difference(blob, H, W), difference)
    assert len(database.encode_difference(np.zeros((H, W, 3), np.int16))) < 1000
    mask = rng.random((H, W)) < 0.3
    np.testing.assert_array_equal(database.decode_mask(database.encode_mask(mask), H, W), mask)
    data, offsets = database.pack_blobs([b"ab", b"", b"cde"])
    assert offsets.tolist() == [0, 2, 2, 5] and bytes(data[offsets[2] : offsets[3]]) == b"cde"


def test_roll_rule():
    rng = np.random.default_rng(0)
    assert np.all(database.sensor_rolls("zero", 5, rng) == 0)
    rolls = database.sensor_rolls("random", 1000, rng)
    assert rolls.min() >= -np.pi and rolls.max() < np.pi and rolls.std() > 1.5
    with pytest.raises(ConfigError):
        database.sensor_rolls("sideways", 5, rng)


def test_body_contact_flag_marks_what_strict_mode_refuses():
    """A sensor pressed 8 mm into a box's face: the box enters the body. It is flagged, strict rendering
    raises on it, and non-strict rendering (what the stages do) draws it."""
    box = trimesh.creation.box(extents=(0.06, 0.06, 0.06))
    normal = np.array([[0.0, 0.0, 1.0]])
    top = np.array([[0.0, 0.0, 0.03]])
    shallow = sensor.sensor_poses_touching(top, normal, 0.0, 0.0018)
    deep = sensor.sensor_poses_touching(top, normal, 0.0, 0.008)
    flags = database.body_contacts(box.vertices, np.concatenate([shallow, deep]))
    assert flags.tolist() == [False, False]  # the box's 8 corners are far from the gel
    dense = box.subdivide().subdivide().subdivide()  # vertices on the face, under the gel
    flags = database.body_contacts(dense.vertices, np.concatenate([shallow, deep]))
    assert flags.tolist() == [False, True]
    background = np.full((H, W, 3), 100, np.uint8)
    with pytest.raises(InputError):
        DigitRenderer.from_default_config(background, strict=True).render(dense, np.eye(4), deep[0])
    assert DigitRenderer.from_default_config(background, strict=False).render(dense, np.eye(4), deep[0]).mask.any()


@pytest.mark.slow
def test_bench_render_prints_json_last(data_dir, capsys):
    from tactile6d.cli import bench_render

    assert bench_render.main(["-n", "16", f"paths.data_dir={data_dir}", "render.workers=1"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["n"] == 16 and summary["images_per_s"] > 0 and summary["workers"] == 1
