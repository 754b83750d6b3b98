"""A unit's no-contact image taken from the first frames of its stream, where nothing touches yet.

A hand's recording usually starts before the fingers close on the object: its first frames show each
DIGIT's gel untouched, under the light of this recording. Their pixel mean is that unit's no-contact image,
with none of the light drift a file recorded earlier may carry and with the camera noise averaged down
(by the square root of the frame count: 7 grey levels in the simulator, 1.8 over 15 frames). It stands in
for a no-contact image recorded apart, and matters most where none was: read against another unit's (the
default is the paper's unit's) an estimate is centimetres off (docs/real_sensors.md), and the pixel median over
scenes that touch (``photometric.background_from_images``) recovers only part of that.

Each of the frames is read against their pixel median (``contact_patch.image_to_patch``; the median, not the
mean, so that one pressed frame leaves no trace in what the others are read against): a frame that shows a
contact there means something touched or moved during them, and the frames cannot serve (an ``InputError``
that names the sensor and the frame). A gel pressed still through most of them passes that test; its press
is then part of the no-contact image, and the frames after read their contacts against it. Start recording
before the fingers touch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tactile6d.core.errors import InputError

if TYPE_CHECKING:
    from tactile6d.perception.contact_patch import PatchModel

MIN_FRAMES = 5  # fewer leave the mean's noise near a single frame's, and a press in one of them barely diluted
DEFAULT_FRAMES = 15  # half a second at 30 frames per second


def still_frames_to_background(frames, model: PatchModel | None = None, sensor: int | None = None) -> np.ndarray:
    """One sensor's first frames (n, 320, 240, 3) uint8 RGB, nothing touching -> its no-contact image
    (320, 240, 3) uint8: the pixel mean, rounded.

    model: the contact patch's calibration that reads each frame against the frames' median (None: the default).
    sensor: its index, for the errors. Raises InputError for fewer than ``MIN_FRAMES`` frames, a bad image,
    or a frame that reads a contact against the median.
    """
    # contact_patch loads the renderer (trimesh): not for `tactile6d track --help`, which reads this module's constants
    from tactile6d.perception.contact_patch import check_image, image_to_patch

    name = "the stream" if sensor is None else f"sensor {sensor}'s stream"
    if len(frames) < MIN_FRAMES:
        raise InputError(f"{name}: {len(frames)} frames to take a no-contact image from; at least {MIN_FRAMES} "
                         f"untouched frames are needed")
    stack = np.stack([check_image(f, f"{name}, frame {k}") for k, f in enumerate(frames)])
    median = np.median(stack, axis=0).round().astype(np.uint8)
    patches = [image_to_patch(frame, median, model) for frame in stack]
    touched = [k for k, patch in enumerate(patches) if patch.contact]
    if touched:
        # A press in a few frames moves the median a little too, so the others may read its trace: the frame
        # with the largest contact is the one named.
        worst = max(touched, key=lambda k: np.count_nonzero(patches[k].mask))
        more = f" (and {len(touched) - 1} more of them)" if len(touched) > 1 else ""
        raise InputError(f"{name}: frame {worst} of the first {len(stack)} shows a contact against the others{more}, "
                         f"so something touched or moved; a no-contact image needs frames where nothing touches "
                         f"(start recording before the fingers close, or pass the no-contact images)")
    return stack.mean(axis=0).round().astype(np.uint8)


def stream_start_to_backgrounds(images, model: PatchModel | None = None) -> np.ndarray:
    """The first frames of a stream (n, L, 320, 240, 3) uint8 RGB -> each sensor's no-contact image
    (L, 320, 240, 3) uint8 (``still_frames_to_background`` per sensor)."""
    images = np.asarray(images)
    if images.ndim != 5:
        raise InputError(f"the stream's first frames must be (n, L, 320, 240, 3), got shape {images.shape}")
    return np.stack([still_frames_to_background(images[:, i], model, i) for i in range(images.shape[1])])
