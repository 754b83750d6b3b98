"""Stage make_scenes end to end in a temporary artifacts directory."""

import numpy as np
import pytest

from stages import make_scenes, prepare_object, sample_surface
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.sim import contact_types
from tactile6d.sim.scenes import CADDEO2023_T_WORLD_OBJECT

pytestmark = pytest.mark.slow  # end-to-end: excluded from the quick subset (-m 'not slow')


def prepare(root: str, obj: str) -> None:
    assert prepare_object.main(["--object", obj, f"paths.artifacts_dir={root}", "prepare.collision=hull"]) == 0
    assert sample_surface.main(["--object", obj, f"paths.artifacts_dir={root}", "sample.M=200"]) == 0


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory, data_dir):
    root = str(tmp_path_factory.mktemp("artifacts"))
    prepare(root, "prim_box")
    return root


def test_caddeo2023_import(artifacts):
    prepare(artifacts, "004_sugar_box")  # a YCB mesh: the slow part
    args = ["--scene-set", "caddeo2023", f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box,004_sugar_box]"]
    assert make_scenes.main(args) == 0
    art = read_artifact(layout.scenes_file(artifacts, "caddeo2023"), "scenes")
    assert art["names"].tolist() == [f"004_sugar_box/triplet_{k}" for k in range(1, 5)]  # the box has no triplets
    assert art["images"].shape == (4, 3, 320, 240, 3)
    np.testing.assert_allclose(art["T_world_object"], np.broadcast_to(CADDEO2023_T_WORLD_OBJECT, (4, 4, 4)))
    assert set(art["contact_types"].ravel()) <= set(range(len(contact_types.CONTACT_TYPES)))


def test_validation_generation(artifacts):
    args = ["--scene-set", "validation", f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box]",
            "scenes.validation.scenes_per_object=2"]
    assert make_scenes.main(args) == 0
    art = read_artifact(layout.scenes_file(artifacts, "validation"), "scenes")
    assert art["images"].shape == (2, 3, 320, 240, 3)
    # every sensor leaves an imprint: its image differs from the others' background noise somewhere strongly
    diff = np.abs(art["images"].astype(int) - np.median(art["images"].reshape(-1, 320, 240, 3), axis=0))
    assert np.all(diff.reshape(2, 3, -1).max(axis=2) > 60)


def test_offaxis_generation_tilts_the_sensors_and_moves_the_imprint_off_centre(artifacts):
    args = ["--scene-set", "offaxis", f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box]",
            "scenes.offaxis.scenes_per_object=2"]
    assert make_scenes.main(args) == 0
    art = read_artifact(layout.scenes_file(artifacts, "offaxis"), "scenes")
    assert art["images"].shape == (2, 3, 320, 240, 3)
    # each sensor's +x axis is within 20 deg of the inward normal at its true contact, and not all along it
    x_axes = art["T_world_sensors"][..., :3, 0]
    tilts = np.degrees(np.arccos(np.clip(np.sum(x_axes * -art["contact_normals"], axis=-1), -1, 1)))
    assert tilts.max() <= 20.0 + 1e-6 and tilts.max() > 2.0
    # the imprint's centre of mass is off the image centre for most sensors (the apex is at the centre)
    diff = np.abs(art["images"].astype(int) - np.median(art["images"].reshape(-1, 320, 240, 3), axis=0)).sum(-1)
    rows, cols = np.mgrid[:320, :240]
    offsets = []
    for d in diff.reshape(-1, 320, 240):
        w = np.where(d > 40, d, 0).astype(float)
        offsets.append(np.hypot((w * rows).sum() / w.sum() - 159.5, (w * cols).sum() / w.sum() - 119.5))
    assert np.median(offsets) > 8  # pixels; about 0.7 mm on the gel


def test_the_calibration_set_is_drawn_from_its_identify_section(artifacts):
    """calibration's spec is identify.calibration_scenes (not a scenes section): its seed and size are
    those, and it is stamped into the file."""
    common = [f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box]",
              "identify.calibration_scenes.scenes_per_object=1"]
    assert make_scenes.main(["--scene-set", "calibration", *common]) == 0
    first = read_artifact(layout.scenes_file(artifacts, "calibration"), "scenes")
    assert first["images"].shape == (1, 3, 320, 240, 3)
    assert first.config["identify.calibration_scenes"]["seed"] == 8
    assert make_scenes.main(["--scene-set", "calibration", *common, "identify.calibration_scenes.seed=9"]) == 0
    other = read_artifact(layout.scenes_file(artifacts, "calibration"), "scenes")
    assert not np.allclose(first["T_world_sensors"], other["T_world_sensors"])


def test_the_confidence_set_is_drawn_from_its_confidence_section(artifacts):
    """confidence's spec is confidence.scenes, with its light and kinematics; stamped into the file."""
    common = [f"paths.artifacts_dir={artifacts}", "objects.names=[prim_box]",
              "confidence.scenes.scenes_per_object=2", "confidence.scenes.light.rerecorded=0.0"]
    assert make_scenes.main(["--scene-set", "confidence", *common]) == 0
    made = read_artifact(layout.scenes_file(artifacts, "confidence"), "scenes")
    assert made["images"].shape == (2, 3, 320, 240, 3)
    assert made.config["confidence.scenes"]["seed"] == 5 and "identify.calibration_scenes" not in made.config
    assert "pose_error_translation" in made and "light_gain" in made  # its kinematics and light
    assert not made["background_rerecorded"].any()  # rerecorded=0: every background the undrifted one
    assert np.all(np.linalg.norm(made["pose_error_translation"], axis=-1) > 0)


def test_unknown_scene_set(artifacts):
    with pytest.raises(SystemExit):
        make_scenes.main(["--scene-set", "nope", f"paths.artifacts_dir={artifacts}"])
