"""tactile6d.perception.stream_background: a unit's no-contact image from the first frames of its stream.

On frames rendered over TACTO's unit (whose LEDs light the gel otherwise than the paper's unit, the default
no-contact image): the mean of its untouched frames reads a press as the unit's own no-contact image does,
where the paper's unit's does not; frames that show a contact are refused, naming the sensor and the frame."""

import numpy as np
import pytest
from test_contact_patch import SPHERE, iou, press
from test_estimator import small_patch_model

from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.perception import contact_patch, stream_background
from tactile6d.perception.encode import load_background
from tactile6d.sim.render import DigitRenderer

TACTO_UNIT = "render.background=digit/tacto/bg_digit_240_320.jpg"


@pytest.fixture(scope="module")
def units(data_dir):
    """A renderer over TACTO's unit (noise 7 grey levels, as the pipeline's) and the two units' recorded no-contact
    images (RGB): TACTO's own and the paper's."""
    own = load_background(compose_config([TACTO_UNIT]), data_dir)
    paper = load_background(compose_config(), data_dir)
    renderer = DigitRenderer.from_default_config(np.ascontiguousarray(own[..., ::-1]))
    return renderer, own, paper


def untouched(renderer, n, seed=0):
    return np.stack([renderer.no_contact(seed=seed + k) for k in range(n)])


def test_the_mean_of_untouched_frames_is_the_units_no_contact_image(units):
    renderer, own, _ = units
    learned = stream_background.still_frames_to_background(untouched(renderer, 15))
    assert learned.shape == (320, 240, 3) and learned.dtype == np.uint8
    # 7 grey levels of noise over 15 frames: 1.8 and the rounding, against 7 for a single frame. The camera (as
    # TACTO's) floors its noisy values, so its frames, and their mean, sit half a grey level under the file's.
    error = learned.astype(float) - own
    single = renderer.no_contact(seed=99).astype(float) - own
    assert abs(error.mean() + 0.5) < 0.2 and error.std() < 2.2 and single.std() > 6.0


@pytest.mark.slow
def test_a_press_reads_against_the_learned_image_as_against_the_units_own(units):
    """A sphere pressed off-centre and tilted, read against the mean of 15 untouched frames: its mask and contact
    point those read against the unit's own no-contact image (IoU > 0.9, within 0.5 mm); against the paper's
    unit's (what the estimator takes when given none) the mask spreads over the gel."""
    renderer, own, paper = units
    model = small_patch_model()
    learned = stream_background.still_frames_to_background(untouched(renderer, 15), model)
    result = press(renderer, contact_patch.shape_to_mesh, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0],
                   tilt_axis=0.5, tilt=0.2, offset=(0.002, -0.001), seed=11)[0]
    reference = contact_patch.image_to_patch(result.image, own, model)
    read = contact_patch.image_to_patch(result.image, learned, model)
    other = contact_patch.image_to_patch(result.image, paper, model)
    assert reference.contact and read.contact
    assert iou(read.mask, reference.mask) > 0.9
    assert np.linalg.norm(read.point - reference.point) < 0.0005
    assert iou(other.mask, reference.mask) < 0.5


@pytest.mark.slow
def test_frames_that_show_a_contact_are_refused_naming_sensor_and_frame(units):
    renderer, _, _ = units
    result = press(renderer, contact_patch.shape_to_mesh, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], seed=5)[0]
    frames = untouched(renderer, 8)
    frames[6] = result.image  # a finger that touched during the first frames
    stream = np.stack([untouched(renderer, 8, seed=50), frames], axis=1)  # (8, 2, ...): sensor 1 touched
    with pytest.raises(InputError, match=r"sensor 1's stream: frame 6 of the first 8 shows a contact"):
        stream_background.stream_start_to_backgrounds(stream)
    both = stream_background.stream_start_to_backgrounds(stream[:6])
    assert both.shape == (2, 320, 240, 3)


def test_too_few_frames_or_a_wrong_shape_is_an_error(units):
    renderer, _, _ = units
    with pytest.raises(InputError, match=f"at least {stream_background.MIN_FRAMES} untouched frames"):
        stream_background.still_frames_to_background(untouched(renderer, stream_background.MIN_FRAMES - 1))
    with pytest.raises(InputError, match=r"must be \(n, L, 320, 240, 3\)"):
        stream_background.stream_start_to_backgrounds(untouched(renderer, 6))
    with pytest.raises(InputError, match="frame 0"):
        stream_background.still_frames_to_background(np.zeros((6, 240, 320, 3), np.uint8))
