"""Stage make_training_set with a tiny count: images, per-image parameters, exact rebuild, bad input."""

import numpy as np
import pytest

from stages import make_training_set
from tactile6d.core import sensor
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, ConfigError
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.data.third_party import DataStore
from tactile6d.sim import contact_types, database
from tactile6d.sim import superquadrics as sq
from tactile6d.sim.render import DigitRenderer, load_background_bgr

pytestmark = pytest.mark.slow  # end-to-end: excluded from the quick subset (-m 'not slow')

N, SHAPES = 12, 3


@pytest.fixture(scope="module")
def built(tmp_path_factory, data_dir):
    artifacts = tmp_path_factory.mktemp("artifacts")
    overrides = [
        f"paths.artifacts_dir={artifacts}",
        f"paths.data_dir={data_dir}",
        f"training_set.n_images={N}",
        f"training_set.n_shapes={SHAPES}",
        "render.workers=1",  # 12 images do not pay for starting worker processes
    ]
    assert make_training_set.main(overrides) == 0
    cfg = compose_config(overrides)
    return cfg, read_artifact(layout.training_set_file(artifacts), "training_set")


def test_images_and_parameters(built):
    cfg, ts = built
    assert database.image_count(ts) == N
    assert ts["shape_index"].tolist() == [0] * 4 + [1] * 4 + [2] * 4
    lo, hi = cfg.training_set.exponent_range
    assert ts["exponents"].shape == (N, 2) and np.all((ts["exponents"] >= lo) & (ts["exponents"] <= hi))
    lo, hi = cfg.training_set.size_range
    assert ts["axes"].shape == (N, 3) and np.all((ts["axes"] >= lo) & (ts["axes"] <= hi))
    lo, hi = cfg.training_set.depth_range
    assert np.all((ts["depths"] >= lo) & (ts["depths"] <= hi))
    assert np.all(np.abs(ts["rolls"]) <= np.pi)
    assert set(ts["kinds"].tolist()) <= {0, 1, 2} and ts.attrs["kind_names"] == list(sq.KIND_NAMES)
    # Every contact touches the shape, so the database points' classifier finds a type for each.
    assert set(ts["contact_types"].tolist()) <= {0, 1, 2, 3}
    assert ts.attrs["contact_type_names"] == list(contact_types.CONTACT_TYPES)
    assert np.mean(ts["mask_pixels"] > 0) >= 0.9
    assert ts.path.stat().st_size < N * 320 * 240 * 3 / 4


def test_sensors_touch_the_superquadric(built):
    _, ts = built
    shape = sq.Superquadric(*ts["axes"][0], *ts["exponents"][0])
    points = sensor.sensor_poses_to_surface_points(ts["T_object_sensor"], ts["depths"])
    on_shape = points[ts["shape_index"] == 0]
    np.testing.assert_allclose(sq.radial_distance(shape, on_shape), 1.0, atol=1e-9)


def test_rebuilt_image_equals_a_direct_render(built):
    cfg, ts = built
    renderer = DigitRenderer.from_config(cfg.render, load_background_bgr(cfg, DataStore(cfg.paths)), workers=1, strict=False)
    i = 5
    shape = sq.Superquadric(*ts["axes"][i], *ts["exponents"][i])
    mesh = sq.superquadric_mesh(shape, cfg.training_set.mesh_max_edge, cfg.training_set.mesh_max_turn)
    direct = renderer.render(mesh, np.eye(4), ts["T_object_sensor"][i], seed=int(ts["noise_seeds"][i]))
    np.testing.assert_array_equal(database.database_images(ts, [i])[0], direct.image)
    np.testing.assert_array_equal(database.database_masks(ts, [i])[0], direct.mask)


def test_two_worker_processes_write_the_same_set(built, tmp_path, data_dir):
    """The shapes rendered on two worker processes come back in order: every dataset equals the one-process set."""
    cfg, ts = built
    overrides = [f"paths.artifacts_dir={tmp_path}", f"paths.data_dir={data_dir}", f"training_set.n_images={N}",
                 f"training_set.n_shapes={SHAPES}", "render.workers=2"]
    assert make_training_set.main(overrides) == 0
    two = read_artifact(layout.training_set_file(tmp_path), "training_set")
    for key in ("images/data", "images/offsets", "masks/data", "mask_pixels", "kinds", "contact_types",
                "body_contact", "noise_seeds", "T_object_sensor", "shape_index"):
        np.testing.assert_array_equal(two[key], ts[key], err_msg=key)


def test_bad_count_and_corrupt_artifact(tmp_path):
    with pytest.raises(ConfigError):
        make_training_set.main([f"paths.artifacts_dir={tmp_path}", "training_set.n_images=0"])
    broken = tmp_path / "training_set.h5"
    broken.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    with pytest.raises(ArtifactError, match="make_training_set"):
        read_artifact(broken, "training_set")
