"""``tactile6d inspect`` on one of the paper's triplets and on copies of it made wrong as a real set-up gets
wrong: it must read what the estimator reads, and list every problem for which the estimator refuses a scene."""

import json
import shutil

import cv2
import numpy as np
import pytest

from tactile6d import cli
from tactile6d.core import geometry as g
from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.core.settings import SelectSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_scene_dir, read_tactile_image, write_tactile_image
from tactile6d.perception import contact_patch, encode
from tactile6d.perception.inputs import check_images_against_backgrounds

TRIPLET = "caddeo2023/triplets/004_sugar_box/triplet_1"


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory):
    """An artifacts directory holding only a small patch calibration (20 presses), as stage calibrate_patch writes it."""
    root = tmp_path_factory.mktemp("artifacts")
    path = layout.patch_model_file(root)
    path.parent.mkdir(parents=True)
    contact_patch.save_model(contact_patch.calibrate(20, seed=0), path)
    return root


@pytest.fixture()
def scene(data_dir, tmp_path):
    """A copy of one of the paper's triplet folders, for a test to spoil."""
    return shutil.copytree(data_dir / TRIPLET, tmp_path / "triplet")


def run(capsys, *argv):
    code = cli.main(["inspect", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def run_json(capsys, scene, artifacts, *more):
    code, out, err = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts), "--json", *more)
    assert err == "" or "error" not in err, err
    return code, json.loads(out)


@pytest.mark.slow
def test_it_reads_the_contacts_the_estimator_reads_and_draws_them(capsys, scene, artifacts, data_dir, tmp_path):
    figure = tmp_path / "figures" / "reading.png"
    code, reading = run_json(capsys, scene, artifacts, "--out", str(figure))
    assert code == 0 and not reading["refused"] and reading["problems"] == []
    assert reading["backgrounds"].startswith("render.background")
    assert [s["contact"] for s in reading["sensors"]] == [True, True, True]

    # The estimator's own reading of the same scene: light alignment, then each image's patch.
    cfg = compose_config([])
    T, images = read_scene_dir(scene)
    background = encode.load_background(cfg, data_dir)
    aligned, _ = encode.align_light(SelectSettings.from_cfg(cfg.select), images, np.stack([background] * 3))
    model = contact_patch.load_model(layout.patch_model_file(artifacts))
    contacts = encode.read_contacts(SelectSettings.from_cfg(cfg.select), T, aligned, background, model)
    for i, s in enumerate(reading["sensors"]):
        point_world = g.transform_points(T[i], np.array(s["point_mm"])[None] / 1000)[0]
        assert np.allclose(point_world, contacts.points[i], atol=1e-5)
        assert 0.0 < s["depth_mm"] < 3.0 and 0.0 < s["area_percent"] <= 100.0 and 0 <= s["tilt_deg"] <= 90
    drawn = cv2.imread(str(figure))
    assert drawn is not None and drawn.shape[0] > drawn.shape[1] > 400  # three rows of four panels


@pytest.mark.slow
def test_the_text_says_where_each_sensor_touches(capsys, scene, artifacts):
    code, out, _ = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts))
    assert code == 0
    lines = out.splitlines()
    assert "render.background" in lines[0]
    for i in range(3):
        line = next(x for x in lines if x.startswith(f"sensor {i}: "))
        assert "contact at pixel row" in line and "mm deep" in line
    assert "would refuse" not in out


@pytest.mark.slow
def test_every_image_the_estimator_refuses_is_named_and_the_others_still_read(capsys, scene, artifacts, data_dir):
    bgr = read_tactile_image(scene / "Image_heatmap_1.png")[..., ::-1]
    write_tactile_image(scene / "Image_heatmap_1.png", np.ascontiguousarray(bgr))
    grey = read_tactile_image(scene / "Image_heatmap_2.png").mean(axis=-1).round().astype(np.uint8)
    write_tactile_image(scene / "Image_heatmap_2.png", np.repeat(grey[..., None], 3, axis=-1))
    code, reading = run_json(capsys, scene, artifacts)
    assert code == 1 and reading["refused"]
    problems = [s["problems"] for s in reading["sensors"]]
    assert problems[0] == []
    assert len(problems[1]) == 1 and "image 1 looks like BGR" in problems[1][0]
    assert len(problems[2]) == 1 and "image 2 is grey" in problems[2][0]
    assert reading["sensors"][0]["contact"] is True
    # The estimator's check stops at the first of them.
    _, images = read_scene_dir(scene)
    background = encode.load_background(compose_config([]), data_dir)
    with pytest.raises(InputError, match="image 1 looks like BGR"):
        check_images_against_backgrounds(images, np.stack([background] * 3))


@pytest.mark.slow
def test_overlapping_sensors_are_a_problem_of_the_scene(capsys, scene, artifacts):
    lines = (scene / "poses_sensors.txt").read_text().splitlines()
    (scene / "poses_sensors.txt").write_text("\n".join([lines[0], lines[0], lines[2]]) + "\n")
    code, out, _ = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts))
    assert code == 1
    assert "problem: sensors 0 and 1 overlap" in out and "would refuse this scene" in out


@pytest.mark.slow
def test_an_untouched_sensor_reads_no_contact(capsys, scene, artifacts, data_dir):
    shutil.copy(data_dir / "digit" / "caddeo2023" / "background.png", scene / "Image_heatmap_0.png")
    code, reading = run_json(capsys, scene, artifacts)
    assert code == 0
    assert reading["sensors"][0]["contact"] is False and "point_mm" not in reading["sensors"][0]
    assert reading["sensors"][1]["contact"] is True


@pytest.mark.slow
def test_drifted_light_is_aligned_before_the_contact_is_read(capsys, scene, artifacts):
    _, clean = run_json(capsys, scene, artifacts)
    image = read_tactile_image(scene / "Image_heatmap_0.png").astype(np.float64)
    write_tactile_image(scene / "Image_heatmap_0.png", np.clip(image * [0.9, 1.0, 1.1], 0, 255).round().astype(np.uint8))
    _, drifted = run_json(capsys, scene, artifacts)
    light, before = drifted["sensors"][0]["light"], clean["sensors"][0]["light"]
    # The fit's gain is the drift's, from the no-contact image's light: red 0.9 times and blue 1.1 times the clean image's.
    ratio = np.divide(light["gain"], before["gain"])
    assert light["applied"] and abs(ratio[0] - 0.9) < 0.05 and abs(ratio[1] - 1.0) < 0.05 and abs(ratio[2] - 1.1) < 0.05
    shift = np.linalg.norm(np.subtract(drifted["sensors"][0]["point_mm"], clean["sensors"][0]["point_mm"]))
    assert shift < 0.5  # mm


def test_light_that_changes_across_the_gel_is_said_and_aligned(capsys, scene, artifacts):
    """One sensor's image brighter towards its last rows and dimmer towards its first, by 5 % at the edges: the
    JSON gives the plane (its row slope undoing the ramp), the text says the light changes across the gel, and the
    contact point moves by less than 0.5 mm. (Sensor 1: the box's face pressed into sensors 0 and 2 covers most of
    their rim, where the plane is fitted, and there the plane is not found.)"""
    _, clean = run_json(capsys, scene, artifacts)
    image = read_tactile_image(scene / "Image_heatmap_1.png").astype(np.float64)
    rows = (np.arange(image.shape[0]) + 0.5) / image.shape[0] * 2.0 - 1.0
    write_tactile_image(scene / "Image_heatmap_1.png",
                        np.clip(image * (1.0 + 0.05 * rows)[:, None, None], 0, 255).round().astype(np.uint8))
    _, uneven = run_json(capsys, scene, artifacts)
    light = uneven["sensors"][1]["light"]
    assert light["applied"] and clean["sensors"][1]["light"]["shading"] is None
    assert all(-0.06 < row < -0.035 for row, _ in light["shading"])  # the image -> no-contact mapping's slope
    shift = np.linalg.norm(np.subtract(uneven["sensors"][1]["point_mm"], clean["sensors"][1]["point_mm"]))
    assert shift < 0.5  # mm
    _, out, _ = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts))
    assert "the light changes across the gel" in out.split("sensor 1:")[1].split("sensor 2:")[0]


@pytest.mark.slow
def test_own_backgrounds_are_taken_as_estimate_takes_them(capsys, scene, artifacts, data_dir):
    background = data_dir / "digit" / "caddeo2023" / "background.png"
    for i in range(3):
        shutil.copy(background, scene / f"background_{i}.png")
    code, reading = run_json(capsys, scene, artifacts)
    assert code == 0 and reading["backgrounds"] == "the folder's background_<i>.png"
    code, reading = run_json(capsys, scene, artifacts, "--background", str(background))
    assert code == 0 and reading["backgrounds"] == "--background"
    code, _, err = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts), "--background", "a.png", "b.png")
    assert code == 2 and "background a.png not found" in err


def test_missing_patch_calibration_names_the_stage_that_makes_it(capsys, scene, tmp_path):
    (tmp_path / "empty").mkdir()
    code, _, err = run(capsys, "--scene", str(scene), "--artifacts", str(tmp_path / "empty"))
    assert code == 2 and "calibrate_patch" in err
    code, _, err = run(capsys, "--scene", str(scene), "--artifacts", str(tmp_path / "nowhere"))
    assert code == 2 and err.startswith(f"error: {tmp_path / 'nowhere'}: no such artifacts directory")


def test_from_scenes_is_refused_where_one_scene_is_read(capsys, scene, artifacts):
    code, _, err = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts), "--background", "from-scenes")
    assert code == 2 and err.startswith("error: --background from-scenes estimates the no-contact images from the "
                                        "images of several scenes, which `tactile6d estimate` and `tactile6d "
                                        "identify` read in one call; `tactile6d inspect` reads one scene")


@pytest.mark.slow
def test_another_units_no_contact_image_is_named_but_the_scene_still_read(capsys, scene, artifacts, data_dir):
    """The paper's triplet read against TACTO's DIGIT's no-contact image: each sensor's light problems say it
    looks like another unit's (a warning: the estimator reads the scene all the same)."""
    other = data_dir / "digit" / "tacto" / "bg_digit_240_320.jpg"
    code, reading = run_json(capsys, scene, artifacts, "--background", str(other))
    assert code == 0 and not reading["refused"]
    for i, s in enumerate(reading["sensors"]):
        assert s["light"]["another_unit"]
        assert any(p.startswith(f"image {i}: its no-contact image looks like another DIGIT unit's")
                   for p in s["light_problems"])
    _, own = run_json(capsys, scene, artifacts)
    assert not any(s["light"]["another_unit"] or s["light_problems"] for s in own["sensors"])
    _, out, _ = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts), "--background", str(other))
    assert "  light warning: image 2: its no-contact image looks like another DIGIT unit's" in out


@pytest.mark.slow
def test_a_bgr_image_is_named_as_such_not_as_another_units(capsys, scene, artifacts):
    """A BGR image agrees with no change of light from its no-contact image; its own problem says why."""
    bgr = read_tactile_image(scene / "Image_heatmap_2.png")[..., ::-1]
    write_tactile_image(scene / "Image_heatmap_2.png", np.ascontiguousarray(bgr))
    code, reading = run_json(capsys, scene, artifacts)
    assert code == 1
    sensor = reading["sensors"][2]
    assert "image 2 looks like BGR" in sensor["problems"][0]
    assert not any("another DIGIT unit" in p for p in sensor["light_problems"])
    assert not sensor["light"]["another_unit"]  # the JSON's fit says what the problems say


@pytest.mark.slow
def test_images_of_a_known_unit_without_their_no_contact_image_are_read_against_it(capsys, scene, artifacts,
                                                                                  data_dir):
    """The paper's triplet moved onto TACTO's DIGIT (each image's difference from the paper's unit's no-contact image
    added to TACTO's), read without --background: each image is read against TACTO's, as the estimator reads it, and
    the reading says so; as if TACTO's had been passed."""
    paper = encode.load_background(compose_config(), data_dir).astype(np.int16)
    name = "TACTO's example DIGIT (digit/tacto/bg_digit_240_320.jpg)"
    tacto = encode.KnownUnits(compose_config(), data_dir).images()[name]
    for i in range(3):
        image = read_tactile_image(scene / f"Image_heatmap_{i}.png").astype(np.int16)
        write_tactile_image(scene / f"Image_heatmap_{i}.png", np.clip(image - paper + tacto, 0, 255).astype(np.uint8))
    write_tactile_image(scene.parent / "tacto.png", tacto)
    code, known = run_json(capsys, scene, artifacts)
    _, given = run_json(capsys, scene, artifacts, "--background", str(scene.parent / "tacto.png"))
    assert code == 0 and [s["known_unit"] for s in known["sensors"]] == [name] * 3
    assert [s["known_unit"] for s in given["sensors"]] == [None] * 3
    for k, g_ in zip(known["sensors"], given["sensors"]):
        assert not k["light"]["another_unit"] and k["light_problems"] == []
        assert {**k, "known_unit": None} == g_
    _, out, _ = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts))
    assert f"  no-contact image: the default looked like another unit's; read against {name}'s" in out


@pytest.mark.slow
def test_images_of_your_own_unit_are_read_against_it_with_known_units(capsys, scene, artifacts, data_dir):
    """The paper's triplet moved onto a unit of the user's whose LEDs differ from every known unit's (the paper's
    unit's no-contact image turned half a turn): read against it with --known-units FOLDER, as if it had been passed;
    without, taken for another unit's that no known unit matches."""
    paper = encode.load_background(compose_config(), data_dir)
    turned = np.ascontiguousarray(paper[::-1, ::-1])
    for i in range(3):
        image = read_tactile_image(scene / f"Image_heatmap_{i}.png").astype(np.int16)
        write_tactile_image(scene / f"Image_heatmap_{i}.png",
                            np.clip(image - paper.astype(np.int16) + turned, 0, 255).astype(np.uint8))
    units = scene.parent / "units"
    units.mkdir()
    write_tactile_image(units / "lab_unit_7.png", turned)
    code, known = run_json(capsys, scene, artifacts, "--known-units", str(units))
    _, given = run_json(capsys, scene, artifacts, "--background", str(units / "lab_unit_7.png"))
    _, plain = run_json(capsys, scene, artifacts)
    assert code == 0 and [s["known_unit"] for s in known["sensors"]] == ["lab_unit_7"] * 3
    for k, g_ in zip(known["sensors"], given["sensors"]):
        assert {**k, "known_unit": None} == g_
    assert all(s["known_unit"] is None and s["light"]["another_unit"] for s in plain["sensors"])
    code, out, err = run(capsys, "--scene", str(scene), "--artifacts", str(artifacts), "--known-units", str(units),
                         "--background", str(units / "lab_unit_7.png"))
    assert code == 2 and "give --background or --known-units, not both" in err
