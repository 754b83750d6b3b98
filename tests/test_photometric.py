"""tactile6d.perception.photometric: an image's light brought back to its no-contact image's.

The fast pieces are checked against naive references; the fit against drifts of known gain and gamma,
on synthetic images and on rendered presses, whose contact point must not move."""

import warnings
from dataclasses import replace

import numpy as np
import pytest
from test_contact_patch import BOX, SPHERE, iou, press
from test_estimator import small_patch_model

from tactile6d.core.settings import SelectSettings
from tactile6d.perception import contact_patch
from tactile6d.perception import encode as encode_step
from tactile6d.perception import photometric
from tactile6d.sim import perturb
from tactile6d.sim import superquadrics as sq
from tactile6d.sim.render import DigitRenderer

H, W = 320, 240


def colourful_background() -> np.ndarray:
    """A smooth synthetic BGR background with spread in every channel (so a gamma can be told from a gain)."""
    rows, cols = np.mgrid[0:H, 0:W]
    return np.stack([60 + cols // 3, 70 + rows // 4, 170 - (rows + cols) // 5], axis=-1).astype(np.uint8)


def noisy(image, sigma, seed):
    rng = np.random.default_rng(seed)
    return np.clip(np.rint(image + rng.normal(0.0, sigma, image.shape)), 0, 255).astype(np.uint8)


# --- the pieces against naive references -------------------------------------------------------------


def _loop_block_means(image, block):
    rows, cols = image.shape[0] // block, image.shape[1] // block
    out = np.empty((rows, cols, image.shape[2]))
    for i in range(rows):
        for j in range(cols):
            out[i, j] = image[block * i:block * i + block, block * j:block * j + block].reshape(-1, image.shape[2]).mean(axis=0)
    return out


@pytest.mark.parametrize("dtype, low, high, channels", [(np.uint8, 0, 256, 3), (np.int16, -255, 256, 3),
                                                        (np.uint8, 0, 256, 1), (np.uint16, 0, 65536, 4)])
def test_block_means_of_whole_numbers_are_a_loops_bits(dtype, low, high, channels):
    # The fast path (OpenCV's area resampling) must give the plain mean's bits: the fits read them.
    image = np.random.default_rng(0).integers(low, high, (13, 10, channels)).astype(dtype)
    out = photometric.block_means(image, 4)
    assert out.shape == (3, 2, channels) and out.dtype == np.float64
    assert np.array_equal(out, _loop_block_means(image, 4))


def test_block_means_of_other_inputs_match_a_loop():
    rng = np.random.default_rng(1)
    floats = rng.normal(100.0, 30.0, (13, 10, 3))
    assert np.allclose(photometric.block_means(floats, 4), _loop_block_means(floats, 4))
    whole = rng.integers(0, 256, (13, 10, 3)).astype(np.uint8)  # a block of 9 pixels: no exact fast path
    assert np.allclose(photometric.block_means(whole, 3), _loop_block_means(whole, 3))


def test_weighted_lines_are_each_rows_least_squares_solution_with_its_prior():
    rng = np.random.default_rng(1)
    x, w = rng.normal(size=(3, 50)), rng.uniform(0.0, 1.0, (3, 50))
    y = 0.3 + 1.4 * x + 0.1 * rng.normal(size=(3, 50))
    prior = np.array([2.0, 0.0, 50.0])
    w[2, :48] = 0.0  # two points and the prior: still one answer
    got = photometric._weighted_lines(x, y, w, prior)
    for c in range(3):
        # Rows sqrt(w) [1, x] -> sqrt(w) y, plus sqrt(prior) [0, 1] -> sqrt(prior) * 1.
        A = np.vstack([np.sqrt(w[c])[:, None] * np.stack([np.ones(50), x[c]], axis=1), [0.0, np.sqrt(prior[c])]])
        b = np.concatenate([np.sqrt(w[c]) * y[c], [np.sqrt(prior[c])]])
        assert np.allclose(got[c], np.linalg.lstsq(A, b, rcond=None)[0])
    # No weight at all: no line to fit, the identity's (0, 1).
    assert np.array_equal(photometric._weighted_lines(x, y, np.zeros((3, 50)), prior), np.tile([0.0, 1.0], (3, 1)))


def test_mode_line_finds_the_tight_line_under_most_points_scattered_off_it():
    rng = np.random.default_rng(2)
    x = rng.uniform(-1.5, -0.3, 1000)
    y = -0.05 + 1.2 * x + rng.normal(0.0, 0.005, 1000)
    y[:700] += rng.uniform(0.02, 0.4, 700)  # 70 % "in contact": brighter by various amounts
    a, b = photometric.mode_line(x, y)
    assert abs(b - 1.2) <= 0.02 and abs(a + 0.05) < 0.02


def test_line_candidates_start_with_the_mode_line_and_are_distinct():
    rng = np.random.default_rng(5)
    x = rng.uniform(-1.5, -0.3, 900)
    y = -0.05 + 1.2 * x + rng.normal(0.0, 0.004, 900)
    y[:300] = 0.1 + 0.8 * x[:300] + rng.normal(0.0, 0.004, 300)  # a second, sparser line
    y[:100] += rng.uniform(0.05, 0.5, 100)
    lines = photometric.line_candidates(x, y, k=5)
    assert len(lines) == 5
    assert tuple(lines[0]) == photometric.mode_line(x, y)
    assert abs(lines[0, 1] - 1.2) <= 0.02
    # The second line is among the candidates ...
    at = np.array([x.min(), np.median(x), x.max()])
    values = lines[:, :1] + lines[:, 1:] * at
    second = 0.1 + 0.8 * at
    assert np.abs(values - second).max(axis=1).min() < photometric.TOLERANCE
    # ... and no two candidates are the same line: each pair differs by more than the tolerance somewhere.
    for i in range(len(lines)):
        for j in range(i):
            assert np.abs(values[i] - values[j]).max() > photometric.TOLERANCE


def test_joint_lines_is_the_combination_the_most_blocks_follow_in_every_channel():
    """Against a naive loop over the combinations; and a line most blocks follow in one channel loses to
    the one they follow in all three."""
    rng = np.random.default_rng(6)
    n = 600
    x = rng.uniform(-1.5, -0.3, (n, 3))
    truth = np.array([[-0.02, 1.1], [0.03, 0.9], [0.0, 1.0]])
    y = truth[:, 0] + truth[:, 1] * x + rng.normal(0.0, 0.003, (n, 3))
    pressed = np.arange(n) >= 150  # a quarter of the blocks untouched
    y[pressed] += rng.uniform(0.05, 0.4, (np.count_nonzero(pressed), 3))
    lure = np.array([0.02, 1.05])  # half the blocks fall on this line in channel 0 alone
    y[150:450, 0] = lure[0] + lure[1] * x[150:450, 0] + rng.normal(0.0, 0.003, 300)
    weights = rng.uniform(0.5, 1.5, n)
    candidates = [photometric.line_candidates(x[:, c], y[:, c], weights) for c in range(3)]
    assert abs(candidates[0][0, 0] - lure[0]) < 0.02 and abs(candidates[0][0, 1] - lure[1]) <= 0.04  # the mode is the lure
    chosen = photometric.joint_lines(x, y, candidates, weights)
    best, best_count = None, -1.0
    for l0 in candidates[0]:
        for l1 in candidates[1]:
            for l2 in candidates[2]:
                follows = np.ones(n, dtype=bool)
                for c, (a, b) in enumerate((l0, l1, l2)):
                    follows &= np.abs(y[:, c] - a - b * x[:, c]) <= photometric.TOLERANCE / 2.0
                count = weights[follows].sum()
                if count > best_count:
                    best, best_count = np.stack([l0, l1, l2]), count
    assert np.array_equal(chosen, best)
    lines, near = photometric.refine_lines(x, y, chosen)
    assert np.allclose(lines, truth, atol=0.01)
    assert near[:150].mean() > 0.95 and near[150:].mean() < 0.05


def test_lookup_tables_are_monotone_and_the_identity_leaves_an_image_as_it_is():
    image = colourful_background()
    assert np.array_equal(photometric.apply_light(image, photometric.IDENTITY), image)
    fit = photometric.LightFit(np.array([0.1, -0.05, 0.0]), np.array([0.9, 1.1, 1.0]), np.zeros(3), 0.0)
    tables = photometric.lookup_tables(fit).astype(int)
    assert np.all(np.diff(tables, axis=1) >= 0)
    # The tables are the model, value by value.
    v = 137
    assert tables[0, v] == round(255 * np.exp(0.1) * (v / 255) ** 0.9)


def test_drift_light_is_the_documented_model():
    image = colourful_background()
    out = perturb.drift_image_light(image, [1.1, 0.9, 1.0], [0.85, 1.2, 1.0])
    v = image[100, 50].astype(float)
    expected = np.rint(255 * np.array([1.1, 0.9, 1.0]) * (v / 255) ** np.array([0.85, 1.2, 1.0]))
    assert np.array_equal(out[100, 50], np.clip(expected, 0, 255))


def test_add_levels_moves_every_4x4_block_by_the_shift():
    """Fractions by ordered dithering: each 4 x 4 block's mean moves by the shift to a 16th of a grey level; a
    whole shift moves every pixel by it; values clip at 0 and 255."""
    image = np.random.default_rng(7).integers(20, 236, (32, 24, 3)).astype(np.uint8)
    shift = np.array([0.5, -1.25, 2.0])
    out = photometric.add_levels(image, shift)
    moved = photometric.block_means(out.astype(np.int16) - image, 4)
    assert np.abs(moved - shift).max() <= 1.0 / 32.0 + 1e-12
    assert np.array_equal(out[..., 2], image[..., 2] + 2)
    assert set(np.unique(out[..., 0].astype(int) - image[..., 0])) == {0, 1}
    ends = np.array([[[0, 128, 255]]], dtype=np.uint8)
    assert photometric.add_levels(ends, [-1.0, 0.0, 1.0]).tolist() == [[[0, 128, 255]]]


def test_untouched_level_is_the_median_over_the_inlier_blocks_of_their_difference():
    rng = np.random.default_rng(8)
    background = rng.integers(30, 200, (40, 32, 3)).astype(np.uint8)
    image = np.clip(background.astype(int) + rng.integers(-3, 3, background.shape), 0, 255).astype(np.uint8)
    inliers = rng.random((10, 8)) < 0.6
    blocks = [(image[4 * i:4 * i + 4, 4 * j:4 * j + 4].reshape(-1, 3).astype(float)
               - background[4 * i:4 * i + 4, 4 * j:4 * j + 4].reshape(-1, 3)).mean(axis=0)
              for i in range(10) for j in range(8) if inliers[i, j]]
    assert np.allclose(photometric.untouched_level(image, background, inliers), np.median(blocks, axis=0))
    assert photometric.untouched_level(image, background, np.zeros((10, 8), dtype=bool)) is None


@pytest.mark.parametrize("gain, offset", [(1.0, -1), (1.0, 0), (0.85, 0)])
def test_align_images_does_what_its_steps_do_one_by_one(gain, offset):
    """``align_images`` makes each image's block means once for the fit and the untouched level: its result is the
    naive sequence's (``fit_light``, no plane of the light, ``apply_light`` where applied, ``untouched_level`` of the image so left,
    ``add_levels``), bit for bit: where the fit is not applied and the image is shifted (its no-contact image a grey
    level darker), where neither happens, and where the fit is applied (a dimmer light)."""
    background = noisy(colourful_background(), 1.0, 3)
    image = noisy(np.clip(colourful_background() * gain, 0, 255), 2.0, 4)
    image[100:180, 80:160] //= 2  # a press's blob, which the fit leaves out
    recorded = np.clip(background.astype(np.int16) + offset, 0, 255).astype(np.uint8)
    aligned, (fit,) = photometric.align_images(image[None], recorded[None])

    naive = photometric.fit_light(image, recorded)
    assert photometric.fit_shading(photometric.block_means(image), photometric.block_means(recorded), naive) is None
    moved = photometric.apply_light(image, naive)
    applied = naive.trustworthy and np.abs(moved.astype(np.int16) - image).mean() >= photometric.MIN_CHANGE
    expected = moved if applied else image
    level = photometric.untouched_level(expected, recorded, naive.inliers)
    shift = photometric.UNTOUCHED_LEVEL - level
    if abs(shift.mean()) >= photometric.LEVEL_TOLERANCE:
        expected = photometric.add_levels(expected, shift)
    assert fit.applied == applied == (gain != 1.0)
    assert np.array_equal(fit.level, level) and np.array_equal(fit.inliers, naive.inliers)
    assert (fit.level_shift is not None) == (offset != 0)
    assert np.array_equal(aligned[0], expected)


def test_apply_light_with_a_plane_against_a_loop():
    """With ``shading`` each pixel gets the log gain of its place: ``255 exp(a + b log(x / 255) + p v + q u)``,
    x floored at 0.5, rounded and clipped; v, u the pixel centre's place from -1 to 1. A flat plane is no plane."""
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (8, 6, 3), dtype=np.uint8)
    fit = photometric.LightFit(np.array([0.05, -0.1, 0.0]), np.array([1.1, 0.9, 1.0]), np.zeros(3), 0.0,
                               shading=np.array([[0.05, -0.02], [0.0, 0.1], [-0.08, 0.03]]))
    out = photometric.apply_light(image, fit)
    for r in range(8):
        for col in range(6):
            v, u = (r + 0.5) / 8 * 2 - 1, (col + 0.5) / 6 * 2 - 1
            for c in range(3):
                x = max(float(image[r, col, c]), 0.5) / 255.0
                value = 255.0 * np.exp(fit.log_gain[c] + fit.exponent[c] * np.log(x) + fit.shading[c, 0] * v
                                       + fit.shading[c, 1] * u)
                assert out[r, col, c] == np.clip(np.rint(value), 0, 255)
    assert np.array_equal(photometric.apply_light(image, replace(fit, shading=np.zeros((3, 2)))),
                          photometric.apply_light(image, replace(fit, shading=None)))


def shaded(image: np.ndarray, slopes) -> np.ndarray:
    """image (H, W, 3) uint8 under a light whose gain per channel is ``1 + p v + q u`` (slopes (3, 2)), rounded."""
    v, u = photometric.centred_coordinates(image.shape[:2])
    gain = 1.0 + np.stack([p * v[:, None] + q * u[None, :] for p, q in slopes], axis=-1)
    return np.clip(np.rint(image * gain), 0, 255).astype(np.uint8)


def test_a_plane_of_light_is_fitted_on_the_rim_and_a_uniform_light_gets_none():
    """A light 5 % brighter on one side than at the centre and 5 % dimmer on the other, in another direction per
    channel, is found (slopes within 0.01 of the log gain's) where a press covers the middle of the gel, which
    the plane is not fitted on; the image aligned is within a grey level of its no-contact image where not pressed.
    A uniform drift, and no drift, get no plane."""
    background = noisy(colourful_background(), 1.0, 3)
    slopes = np.array([[0.05, 0.0], [0.0, -0.05], [0.035, 0.035]])
    image = noisy(shaded(background, slopes), 1.0, 4)
    image[80:240, 60:180] = image[80:240, 60:180] // 2 + 60  # a press's colours over the middle
    aligned, (fit,) = photometric.align_images(image[None], background[None])
    assert fit.shading is not None and fit.applied
    assert np.abs(fit.shading + slopes).max() < 0.01  # the image -> no-contact mapping undoes the ramp
    assert fit.to_dict()["shading"] == np.round(fit.shading, 4).tolist()
    untouched = np.ones((H, W), dtype=bool)
    untouched[76:244, 56:184] = False
    assert np.abs(aligned[0].astype(float) - background)[untouched].mean() < 1.0
    assert np.abs(image.astype(float) - background)[untouched].mean() > 2.5
    for changed in (np.clip(background * 1.08, 0, 255).astype(np.uint8), background):
        _, (flat,) = photometric.align_images(noisy(changed, 1.0, 6)[None], background[None])
        assert flat.shading is None and flat.to_dict()["shading"] is None


# --- the fit -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("gain, gamma", [([1.1, 0.92, 1.0], [0.85, 1.15, 1.05]), ([0.9, 1.08, 1.06], [1.2, 0.9, 0.83])])
def test_a_drift_is_recovered_under_a_contact_that_covers_most_of_the_gel(gain, gamma):
    background = colourful_background()
    rows, cols = np.mgrid[0:H, 0:W]
    # A press lights up an ellipse over half the image, most where it presses most; outside, nothing changes.
    blob = np.sqrt(np.clip(1.0 - ((rows - 150) / 135.0) ** 2 - ((cols - 120) / 100.0) ** 2, 0.0, None))
    assert (blob > 0).mean() > 0.5
    touched = np.clip(background + blob[..., None] * np.array([40.0, 25.0, 30.0]), 0, 255)
    image = noisy(perturb.drift_image_light(touched.astype(np.uint8), gain, gamma), 2.0, 3)
    fit = photometric.fit_light(image, background)
    # Gain and gamma trade off over a channel's narrow range of values; the mapping itself is what counts:
    # each value the background takes, drifted and mapped back, within 2 grey levels.
    tables = photometric.lookup_tables(fit).astype(int)
    for c in range(3):
        values = np.unique(background[..., c])
        drifted = perturb.drift_image_light(np.repeat(values[:, None], 3, axis=1)[None], gain, gamma)[0, :, c]
        assert np.abs(tables[c][drifted] - values).max() <= 2, c
    aligned = photometric.apply_light(image, fit).astype(float)
    assert np.abs(aligned - touched).mean() < 2.0 < np.abs(image.astype(float) - touched).mean()
    assert fit.trustworthy


def test_an_image_under_its_own_light_is_left_nearly_as_it_is():
    background = colourful_background()
    image = noisy(background, 7.0, 4)
    fit = photometric.fit_light(image, background)
    assert np.allclose(fit.gain, 1.0, atol=0.01) and np.allclose(fit.gamma, 1.0, atol=0.01)
    assert np.abs(photometric.apply_light(image, fit).astype(int) - image).max() <= 2


def test_light_far_beyond_a_units_drift_is_reported_and_not_applied():
    background = colourful_background()
    dimmed = perturb.drift_image_light(background, 0.4, 1.0)
    fit = photometric.fit_light(dimmed, background)
    assert not fit.trustworthy and "gain" in fit.problems()[0]
    aligned, (reported,) = photometric.align_images(dimmed[None], background[None])
    assert np.array_equal(aligned[0], dimmed) and not reported.applied
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        photometric.warn_about_light(np.stack([background, dimmed]), np.stack([background] * 2),
                                     [photometric.IDENTITY, fit])
    messages = [str(w.message) for w in caught if w.category is photometric.LightWarning]
    assert messages and all(m.startswith("image 1: its light would differ by a gain") for m in messages)


def test_a_fit_that_changes_an_image_by_less_than_the_threshold_is_not_applied():
    background = colourful_background()
    slight = perturb.drift_image_light(background, 1.01, 1.0)  # about 1 grey level
    aligned, (fit,) = photometric.align_images(slight[None], background[None])
    assert not fit.applied and fit.trustworthy
    # Not aligned; but, noise-free and a grey level brighter, it is that far off the renderer's level: shifted onto it.
    assert np.array_equal(aligned[0], photometric.add_levels(slight, fit.level_shift))
    assert np.allclose(fit.level + fit.level_shift, photometric.UNTOUCHED_LEVEL)
    drifted = perturb.drift_image_light(background, 1.1, 0.9)
    aligned, (fit,) = photometric.align_images(drifted[None], background[None])
    assert fit.applied and np.abs(aligned[0].astype(int) - background).mean() < 1.0


def test_a_units_background_is_the_median_of_its_images():
    background = colourful_background()
    images = []
    for k in range(5):
        image = background.copy()
        image[40 * k:40 * k + 40] = 255  # each press somewhere else
        images.append(image)
    assert photometric.background_from_images(np.stack(images[:4])) is None
    assert np.array_equal(photometric.background_from_images(np.stack(images)), background)


# --- a rendered press under drifted light ------------------------------------------------------------


@pytest.fixture(scope="module")
def renderer():
    return DigitRenderer.from_default_config(colourful_background())


# A sphere, a box's edge and a box's face pressed 0.8 mm (a face pressed 1.8 mm lights up nearly the whole gel
# with an almost uniform shift: there the point moves by about 1 mm, docs/real_sensors.md).
EDGE = sq.project_to_surface(BOX, np.array([[-1.0, -1.0, 0.0]]))[0]
PRESSES = {
    "sphere": (SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], 0.0018),
    "box edge": (BOX, EDGE, sq.surface_normals(BOX, EDGE[None])[0], 0.0018),
    "box face": (BOX, [-0.03, 0.004, -0.003], [-1.0, 0.0, 0.0], 0.0008),
}
DRIFTS = [([1.1, 0.9, 1.05], [0.83, 1.2, 0.9]), ([0.9, 1.1, 0.95], [1.2, 0.85, 1.1])]


@pytest.mark.parametrize("drift", DRIFTS)
@pytest.mark.parametrize("name", PRESSES)
@pytest.mark.slow
def test_a_rendered_press_under_drifted_light_gives_the_same_contact_point(renderer, name, drift):
    """Issue 34's test: the same press read through a gain/gamma change (+-10 %, gamma 0.83-1.2, noise 2)
    gives the contact point of the press under the no-contact image's light within 0.5 mm; read as given,
    it does not."""
    shape, point, normal, depth = PRESSES[name]
    gain, gamma = drift
    model = small_patch_model()
    cache = {}
    result, p_true, _, _ = press(renderer, lambda s: cache.setdefault(s, contact_patch.shape_to_mesh(s)), shape, point,
                                 normal, depth=depth, tilt_axis=0.5, tilt=0.2, offset=(0.002, -0.001), seed=11)
    no_contact = renderer.no_contact(seed=12)
    reference = contact_patch.image_to_patch(result.image, no_contact, model)
    drifted = noisy(perturb.drift_image_light(result.image, gain, gamma), 2.0, 13)
    settings = SelectSettings.from_cfg(_select_section())
    aligned, fits = encode_step.align_light(settings, drifted[None], no_contact)
    read = contact_patch.image_to_patch(aligned[0], no_contact, model)
    as_given = contact_patch.image_to_patch(drifted, no_contact, model)
    assert read.contact and fits[0].trustworthy
    assert np.linalg.norm(read.point - reference.point) < 0.0005
    assert np.linalg.norm(as_given.point - reference.point) > 0.002


@pytest.mark.parametrize("gain, offset", [(0.985, 0.0), (1.0, -1.5)])
@pytest.mark.slow
def test_a_slight_change_of_light_is_aligned_before_the_mask_reads_it(renderer, gain, offset):
    """A light 1.5 % dimmer, or 1.5 grey levels darker (an exposure step, LEDs warming up after the no-contact
    image was recorded), moves the image by about 2 grey levels, under the 2.5 that ``MIN_CHANGE`` was: read as
    given against a recorded (noise-free) no-contact image, the contact mask spills over the untouched gel, and
    an untouched image reads as touched. Aligned, the press reads the mask it reads under the no-contact image's
    light, and the untouched image no contact."""
    shape, point, normal, depth = PRESSES["sphere"]
    model = small_patch_model()
    result = press(renderer, contact_patch.shape_to_mesh, shape, point, normal, depth=depth, tilt_axis=0.5,
                   tilt=0.2, offset=(0.002, -0.001), seed=11)[0]
    recorded = DigitRenderer.from_default_config(colourful_background(), noise_std=0.0).no_contact()
    rng = np.random.default_rng(3)

    def slightly(image):  # the change, each value rounded at random (dither), as a camera's noise would
        x = image.astype(np.float64) * gain + offset
        return np.clip(np.floor(x + rng.random(x.shape)), 0, 255).astype(np.uint8)

    reference = contact_patch.image_to_patch(result.image, recorded, model)
    changed = slightly(result.image)
    aligned, (fit,) = photometric.align_images(changed[None], recorded[None])
    read = contact_patch.image_to_patch(aligned[0], recorded, model)
    as_given = contact_patch.image_to_patch(changed, recorded, model)
    assert fit.applied and read.contact
    assert iou(read.mask, reference.mask) > 0.95 and iou(as_given.mask, reference.mask) < 0.9
    assert np.linalg.norm(read.point - reference.point) < 0.0005
    untouched = slightly(renderer.no_contact(seed=14))
    aligned, (fit,) = photometric.align_images(untouched[None], recorded[None])
    assert fit.applied and not contact_patch.image_to_patch(aligned[0], recorded, model).contact
    assert contact_patch.image_to_patch(untouched, recorded, model).contact


@pytest.mark.parametrize("name", PRESSES)
@pytest.mark.slow
def test_an_image_a_grey_level_off_the_renderers_level_is_shifted_onto_it(renderer, name):
    """The renderer's presses sit at ``UNTOUCHED_LEVEL`` against their no-contact image and are left as they are;
    against that image recorded one grey level brighter (the press 1.5 levels under it, too little for the fit to
    be applied) they are shifted back onto it, and read the mask and contact point of their own image (IoU over
    0.99, within 0.03 mm), which as given they do not (IoU under 0.98, more than 0.05 mm off). ``apply_fit``
    repeats the shift on the same image."""
    shape, point, normal, depth = PRESSES[name]
    model = small_patch_model()
    result = press(renderer, contact_patch.shape_to_mesh, shape, point, normal, depth=depth, tilt_axis=0.5,
                   tilt=0.2, offset=(0.002, -0.001), seed=11)[0]
    recorded = DigitRenderer.from_default_config(colourful_background(), noise_std=0.0).no_contact()
    aligned, (own,) = photometric.align_images(result.image[None], recorded[None])
    assert np.array_equal(aligned[0], result.image) and own.level_shift is None
    assert np.abs(own.level - photometric.UNTOUCHED_LEVEL).max() < 0.15
    brighter = recorded + np.uint8(1)
    aligned, (fit,) = photometric.align_images(result.image[None], brighter[None])
    assert not fit.applied and fit.level_shift is not None and abs(fit.level_shift.mean() - 1.0) < 0.2
    assert np.abs(photometric.untouched_level(aligned[0], brighter, fit.inliers) - photometric.UNTOUCHED_LEVEL).max() < 0.1
    assert np.array_equal(photometric.apply_fit(result.image, fit), aligned[0])
    reference = contact_patch.image_to_patch(result.image, recorded, model)
    read = contact_patch.image_to_patch(aligned[0], brighter, model)
    as_given = contact_patch.image_to_patch(result.image, brighter, model)
    assert iou(read.mask, reference.mask) > 0.99 > 0.98 > iou(as_given.mask, reference.mask)
    assert np.linalg.norm(read.point - reference.point) < 3e-5 < 5e-5 < np.linalg.norm(as_given.point - reference.point)
    assert fit.to_dict()["level_shift"] == np.round(fit.level_shift, 2).tolist()


@pytest.mark.parametrize("name", PRESSES)
@pytest.mark.slow
def test_a_rendered_press_under_uneven_light_reads_its_own_contact(renderer, name):
    """A rendered press whose light is 5 % brighter at one edge than at the centre and 5 % dimmer at the other (in
    another direction per channel, as when each of a DIGIT's LEDs drifts its own way), read against the no-contact
    image of before: aligned with the plane of the light, its mask is the one of the press under its own light
    (IoU over 0.9; as given under 0.5: the brighter side reads as contact) and its contact point within 1 mm of
    that press's (the box's face, a broad flat press, moves most); the same press under its own light gets no
    plane."""
    shape, point, normal, depth = PRESSES[name]
    model = small_patch_model()
    result = press(renderer, contact_patch.shape_to_mesh, shape, point, normal, depth=depth, tilt_axis=0.5,
                   tilt=0.2, offset=(0.002, -0.001), seed=11)[0]
    recorded = renderer.no_contact(seed=12)
    reference = contact_patch.image_to_patch(result.image, recorded, model)
    _, (own,) = photometric.align_images(result.image[None], recorded[None])
    assert own.shading is None
    uneven = shaded(result.image, np.array([[0.05, 0.0], [-0.035, 0.035], [0.0, -0.05]]))
    aligned, (fit,) = photometric.align_images(uneven[None], recorded[None])
    assert fit.shading is not None and fit.applied
    read = contact_patch.image_to_patch(aligned[0], recorded, model)
    as_given = contact_patch.image_to_patch(uneven, recorded, model)
    assert iou(read.mask, reference.mask) > 0.9 > 0.5 > iou(as_given.mask, reference.mask)
    assert np.linalg.norm(read.point - reference.point) < 0.001


@pytest.mark.parametrize("gain, gamma", [([0.92, 1.06, 0.97], [1.12, 0.88, 1.05]), ([1.08, 0.93, 1.04], [0.86, 1.15, 0.9])])
@pytest.mark.slow
def test_a_drift_is_recovered_under_a_press_over_most_of_the_gel(data_dir, gain, gamma):
    """A ball of 5 cm radius pressed 2.5 mm over the paper's unit's no-contact image leaves under a third of
    the gel untouched; under a drift the fit still finds the light there (each channel's gain within 0.04),
    where a search per channel let the press's colours pull it (0.06 and 0.07 off in these two drifts)."""
    from tactile6d.core.config import compose_config
    from tactile6d.perception.encode import load_background

    background = np.ascontiguousarray(load_background(compose_config(), data_dir)[..., ::-1])  # BGR, as rendered
    r = DigitRenderer.from_default_config(background)
    ball = sq.Superquadric(0.05, 0.05, 0.05, 1.0, 1.0)
    result = press(r, contact_patch.shape_to_mesh, ball, [-0.05, 0.0, 0.0], [-1.0, 0.0, 0.0], depth=0.0025, seed=5)[0]
    assert (result.depth > 0).mean() > 0.65
    drifted = noisy(perturb.drift_image_light(result.image, gain, gamma), 2.0, 7)
    fit = photometric.fit_light(drifted, r.no_contact(seed=6))
    assert np.abs(fit.gain - gain).max() < 0.04, (fit.gain, fit.gamma)
    assert fit.trustworthy and not fit.from_another_unit


def _select_section() -> dict:
    from tactile6d.core.config import compose_config

    return dict(compose_config().select)


@pytest.mark.slow
def test_alignment_is_off_for_the_baseline_and_without_a_no_contact_image():
    images = colourful_background()[None]
    off = SelectSettings.from_cfg({**_select_section(), "method": "baseline"})
    assert encode_step.align_light(off, images, colourful_background()) == (images, None)
    on = SelectSettings.from_cfg(_select_section())
    assert encode_step.align_light(on, images, None) == (images, None)


# --- a no-contact image of another unit ------------------------------------------------------------


@pytest.fixture(scope="module")
def two_units(data_dir):
    """The same three presses (a sphere, a box's edge, a box's face pressed 1.8 mm over most of the gel)
    rendered over two units' no-contact images, the paper's DIGIT's and TACTO's -> {unit: (images (3, H, W,
    3), its no-contact image)}, RGB."""
    import cv2

    from tactile6d.core.config import compose_config
    from tactile6d.perception.encode import load_background

    paper = load_background(compose_config(), data_dir)
    tacto = cv2.imread(str(data_dir / "digit" / "tacto" / "bg_digit_240_320.jpg"))
    if tacto is None:
        pytest.skip("TACTO's background image is not in the data directory")
    presses = [PRESSES["sphere"], PRESSES["box edge"], (*PRESSES["box face"][:3], 0.0018)]
    cache = {}
    out = {}
    for unit, bgr in (("paper", np.ascontiguousarray(paper[..., ::-1])), ("tacto", tacto)):
        r = DigitRenderer.from_default_config(bgr)
        images = [press(r, lambda s: cache.setdefault(s, contact_patch.shape_to_mesh(s)), shape, point, normal,
                        depth=depth, seed=20 + k)[0].image for k, (shape, point, normal, depth) in enumerate(presses)]
        out[unit] = (np.stack(images), r.no_contact(seed=30))
    return out


@pytest.mark.slow
def test_a_no_contact_image_of_another_unit_is_told_apart(two_units):
    """Against its own unit's no-contact image every press agrees where the gel is not pressed (drifted
    light too); against the other unit's hardly anywhere, and each image says so."""
    for unit, other in (("paper", "tacto"), ("tacto", "paper")):
        images, own = two_units[unit]
        drifted = np.stack([noisy(perturb.drift_image_light(im, [1.1, 0.9, 1.05], [0.83, 1.2, 0.9]), 2.0, 5)
                            for im in images])
        for batch in (images, drifted):
            fits = [photometric.fit_light(im, own) for im in batch]
            assert not any(f.from_another_unit for f in fits), [f.agreement for f in fits]
            assert photometric.unit_problems(batch, np.stack([own] * 3), fits) == [None] * 3
        wrong = np.stack([two_units[other][1]] * 3)
        fits = [photometric.fit_light(im, bg) for im, bg in zip(images, wrong)]
        assert all(f.from_another_unit for f in fits), [f.agreement for f in fits]
        problems = photometric.unit_problems(images, wrong, fits)
        for i, problem in enumerate(problems):
            assert problem.startswith(f"image {i}: its no-contact image looks like another DIGIT unit's")
            assert "record this unit's no-contact image" in problem


def test_no_contact_images_given_in_another_order_are_named(two_units):
    images = np.stack([two_units["paper"][0][0], two_units["tacto"][0][1]])
    swapped = np.stack([two_units["tacto"][1], two_units["paper"][1]])
    fits = [photometric.fit_light(im, bg) for im, bg in zip(images, swapped)]
    first, second = photometric.unit_problems(images, swapped, fits)
    assert "it agrees with sensor 1's no-contact image" in first and "another order than the sensors" in first
    assert "it agrees with sensor 0's no-contact image" in second
    # Warned about as another unit's, and nothing else: a fit's drift, out of range here for one, says nothing then.
    assert not all(f.trustworthy for f in fits)
    with pytest.warns(photometric.UnitWarning) as caught:
        photometric.warn_about_light(images, swapped, fits)
    assert [str(w.message) for w in caught] == [first, second]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        right = np.stack([two_units["paper"][1], two_units["tacto"][1]])
        photometric.warn_about_light(images, right, [photometric.fit_light(im, bg) for im, bg in zip(images, right)])


@pytest.mark.slow
def test_an_image_of_another_unit_is_matched_to_the_known_unit_it_agrees_with(two_units):
    """Each unit's images, fitted against the other unit's no-contact image, agree with their own among the known
    units, and with none when their own is not among them; images fitted against their own are not looked at."""
    for unit, other in (("paper", "tacto"), ("tacto", "paper")):
        images, own = two_units[unit]
        fits = [photometric.fit_light(im, two_units[other][1]) for im in images]
        found = photometric.known_units_agreeing(images, fits, {other: two_units[other][1], unit: own})
        assert sorted(found) == [0, 1, 2] and {name for name, _ in found.values()} == {unit}
        for i, (_, fit) in found.items():
            assert fit.agreement == photometric.fit_light(images[i], own).agreement >= photometric.MIN_AGREEMENT
        assert photometric.known_units_agreeing(images, fits, {other: two_units[other][1]}) == {}
        own_fits = [photometric.fit_light(im, own) for im in images]
        assert photometric.known_units_agreeing(images, own_fits, {other: two_units[other][1]}) == {}
        with pytest.warns(photometric.KnownUnitWarning, match=rf"image 0: .* agrees with {unit}'s on \d+ % of its"):
            photometric.warn_about_known_units({0: found[0]})


def test_unit_likeness_is_the_rank_correlation_of_the_block_means_least_over_the_channels():
    """Against a naive Spearman's rho, channel by channel: the correlation of scipy's ranks, ties ranked in the
    blocks' order as ``unit_likeness`` ranks them."""
    from scipy.stats import rankdata

    def spearman(a, b):
        return np.corrcoef(rankdata(a, method="ordinal"), rankdata(b, method="ordinal"))[0, 1]

    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (320, 240, 3), dtype=np.uint8)
    units = {"a": rng.integers(0, 256, (320, 240, 3), dtype=np.uint8),
             "b": np.clip(image.astype(int) + rng.integers(-30, 30, image.shape), 0, 255).astype(np.uint8)}
    mine = photometric.block_means(image, photometric.LIKENESS_BLOCK)
    likeness = photometric.unit_likeness(image, units)
    assert photometric.unit_likeness(image, units, photometric.unit_ranks(units)) == likeness  # ranks made once
    for name, unit in units.items():
        theirs = photometric.block_means(unit, photometric.LIKENESS_BLOCK)
        naive = min(spearman(mine[..., c].ravel(), theirs[..., c].ravel()) for c in range(3))
        assert likeness[name] == pytest.approx(naive, abs=1e-12)
    assert likeness["b"] > 0.9 > 0.2 > abs(likeness["a"])
    # A change of gain and gamma keeps the order of brightness: the likeness of a unit to itself stays 1.
    drifted = np.clip(255 * (image / 255.0) ** 1.15 * 0.9, 0, 255).astype(np.uint8)
    assert photometric.unit_likeness(drifted, {"a": image})["a"] > 0.99


@pytest.mark.slow
def test_a_drawer_of_units_is_screened_by_likeness_before_it_is_fitted(two_units, monkeypatch):
    """Among many known units only the SCREENED_UNITS most alike each image are fitted, and its own is among them:
    the same answer as fitting every unit, for a fraction of the fits."""
    units = {"paper": two_units["paper"][1], "tacto": two_units["tacto"][1]}
    for name, background in list(units.items()):
        units[f"{name} turned"] = np.ascontiguousarray(background[::-1, ::-1])
        units[f"{name} mirrored"] = np.ascontiguousarray(background[:, ::-1])
    images, own = two_units["tacto"]
    fits = [photometric.fit_light(im, two_units["paper"][1]) for im in images]
    fitted = []
    real_fit = photometric.fit_light
    monkeypatch.setattr(photometric, "fit_light", lambda image, background: fitted.append(1) or real_fit(image, background))
    found = photometric.known_units_agreeing(images, fits, units)
    assert {i: name for i, (name, _) in found.items()} == {0: "tacto", 1: "tacto", 2: "tacto"}
    assert len(fitted) == len(images) * photometric.SCREENED_UNITS < len(images) * len(units)
    monkeypatch.setattr(photometric, "SCREENED_UNITS", len(units))  # every unit fitted: the same answer
    everything = photometric.known_units_agreeing(images, fits, units)
    assert {i: (n, f.agreement) for i, (n, f) in everything.items()} == {i: (n, f.agreement) for i, (n, f) in found.items()}
