"""A sequence of tactile frames on disk as numbered scene folders.

Layout of a sequence folder ``DIR``::

    DIR/000000/poses_sensors.txt        one "x y z ax ay az angle" line per sensor (T_world_sensor, metres, radians)
    DIR/000000/Image_heatmap_<i>.png    sensor i's image, 240 wide x 320 high, for i = 0..L-1
    DIR/000000/background_<i>.png       optional: sensor i's no-contact image for this frame only
    DIR/000001/...
    DIR/background_<i>.png              optional: sensor i's no-contact image, shared by every frame
    DIR/frames.json                     optional: {"stamps": [seconds, one per frame folder], "fps": frames per second}

Each frame folder is a scene folder in the paper's layout (``tactile6d.data.hdf5.read_scene_dir``). Frame folders are
those whose names are all digits, in numeric order (``000010`` after ``000009``; other entries are ignored). A
frame's timestamp is ``frames.json``'s ``stamps[k]`` for the k-th frame folder, else its folder number / ``fps``,
else None. Every frame has the same number L of sensors.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import poses_to_text
from tactile6d.data.hdf5 import (
    SCENE_BACKGROUND,
    TACTILE_IMAGE_SHAPE,
    read_scene_backgrounds,
    read_scene_dir,
    write_json,
    write_tactile_image,
    write_text,
)

FRAMES_JSON = "frames.json"
FRAME_DIGITS = 6  # frame folder names written: 000000, 000001, ...

# One frame of a sequence: (index: the folder's number, stamp: seconds or None, T_world_sensors (L, 4, 4),
# images (L, 320, 240, 3) uint8 RGB, backgrounds (L, 320, 240, 3) uint8 RGB or None).
SequenceFrame = tuple[int, float | None, np.ndarray, np.ndarray, np.ndarray | None]


def _check_images(images: np.ndarray, leading: tuple[int, ...], what: str) -> np.ndarray:
    images = np.asarray(images)
    if images.shape != leading + TACTILE_IMAGE_SHAPE or images.dtype != np.uint8:
        raise InputError(f"{what}: expected uint8 of shape {leading + TACTILE_IMAGE_SHAPE}, got {images.dtype} "
                         f"{images.shape}")
    return images


def write_sequence_dir(
    directory: str | os.PathLike,
    T_world_sensors: np.ndarray,
    images: np.ndarray,
    backgrounds: np.ndarray | None = None,
    stamps: np.ndarray | None = None,
    fps: float | None = None,
) -> Path:
    """Write a sequence of F frames of L sensors as numbered scene folders ``directory/000000/`` ... -> directory.

    T_world_sensors (F, L, 4, 4) metres; images (F, L, 320, 240, 3) uint8 RGB; backgrounds: the sensors' no-contact
    images, (L, 320, 240, 3) shared by every frame (``directory/background_<i>.png``) or (F, L, 320, 240, 3), one set
    per frame (in each frame folder); stamps (F,) seconds, strictly increasing, and fps go to ``frames.json``
    (written only when one of them is given). The directory must be absent or empty (InputError otherwise).
    """
    directory = Path(directory)
    T = np.asarray(T_world_sensors, dtype=np.float64)
    if T.ndim != 4 or T.shape[2:] != (4, 4):
        raise InputError(f"{directory}: T_world_sensors must have shape (F, L, 4, 4), got {T.shape}")
    n_frames, n_sensors = T.shape[:2]
    images = _check_images(images, (n_frames, n_sensors), f"{directory}: images")
    if backgrounds is not None:
        backgrounds = np.asarray(backgrounds)
        leading = (n_sensors,) if backgrounds.ndim == 4 else (n_frames, n_sensors)
        backgrounds = _check_images(backgrounds, leading, f"{directory}: backgrounds")
    frames_json: dict = {}
    if stamps is not None:
        stamps = np.asarray(stamps, dtype=np.float64)
        if stamps.shape != (n_frames,) or not np.all(np.isfinite(stamps)) or np.any(np.diff(stamps) <= 0):
            raise InputError(f"{directory}: stamps must be ({n_frames},) finite, strictly increasing seconds")
        frames_json["stamps"] = stamps.tolist()
    if fps is not None:
        if not (math.isfinite(fps) and fps > 0):
            raise InputError(f"{directory}: fps {fps} must be a positive number")
        frames_json["fps"] = float(fps)
    if directory.exists() and (not directory.is_dir() or any(directory.iterdir())):
        raise InputError(f"{directory}: exists and is not an empty folder; a sequence is written to a new one")
    directory.mkdir(parents=True, exist_ok=True)
    if backgrounds is not None and backgrounds.ndim == 4:
        for i, image in enumerate(backgrounds):
            write_tactile_image(directory / SCENE_BACKGROUND.format(i), image)
    for f in range(n_frames):
        frame_dir = directory / f"{f:0{FRAME_DIGITS}d}"
        frame_dir.mkdir()
        write_text(frame_dir / "poses_sensors.txt", poses_to_text(T[f]))
        for i in range(n_sensors):
            write_tactile_image(frame_dir / f"Image_heatmap_{i}.png", images[f, i])
            if backgrounds is not None and backgrounds.ndim == 5:
                write_tactile_image(frame_dir / SCENE_BACKGROUND.format(i), backgrounds[f, i])
    if frames_json:
        write_json(directory / FRAMES_JSON, frames_json)
    return directory


def sequence_dir_frames(directory: str | os.PathLike) -> list[Path]:
    """The frame folders of a sequence folder (sub-folders whose names are all digits), in numeric order.
    InputError naming the directory when it is missing, holds none, or holds two with the same number."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"sequence folder {directory} not found")
    frames = sorted((p for p in directory.iterdir() if p.is_dir() and p.name.isascii() and p.name.isdigit()),
                    key=lambda p: (int(p.name), p.name))
    if not frames:
        raise InputError(f"{directory}: no frame folders (sub-folders named by frame number: 000000, 000001, ...)")
    for before, after in zip(frames, frames[1:]):
        if int(before.name) == int(after.name):
            raise InputError(f"{directory}: frame folders {before.name} and {after.name} have the same number")
    return frames


def _read_frames_json(directory: Path, frames: list[Path]) -> list[float | None]:
    """Each frame folder's stamp in seconds (None for all when there is no frames.json, or neither key)."""
    path = directory / FRAMES_JSON
    if not path.is_file():
        return [None] * len(frames)
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not readable JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise InputError(f"{path}: must be a JSON object with keys 'stamps' and/or 'fps'")
    if meta.get("stamps") is not None:
        stamps = meta["stamps"]
        if not isinstance(stamps, list) or not all(
            isinstance(s, (int, float)) and not isinstance(s, bool) and math.isfinite(s) for s in stamps
        ):
            raise InputError(f"{path}: 'stamps' must be a list of numbers (seconds)")
        if len(stamps) != len(frames):
            raise InputError(f"{path}: {len(stamps)} stamps for {len(frames)} frame folders")
        if any(b <= a for a, b in zip(stamps, stamps[1:])):
            raise InputError(f"{path}: 'stamps' must be strictly increasing")
        if stamps and stamps[0] < 0:
            raise InputError(f"{path}: 'stamps' must be seconds >= 0 (ROS time), got {stamps[0]} for frame folder "
                             f"{frames[0].name}")
        return [float(s) for s in stamps]
    if meta.get("fps") is not None:
        fps = meta["fps"]
        if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and fps > 0):
            raise InputError(f"{path}: 'fps' must be a positive number, got {fps!r}")
        return [int(p.name) / fps for p in frames]
    return [None] * len(frames)


def iter_sequence_dir(directory: str | os.PathLike) -> Iterator[SequenceFrame]:
    """The frames of a sequence folder, read one at a time, in numeric order -> an iterator of
    (index, stamp, T_world_sensors, images, backgrounds) (``SequenceFrame``).

    index: the frame folder's number; stamp: seconds or None (module docstring); T_world_sensors (L, 4, 4) metres;
    images (L, 320, 240, 3) uint8 RGB; backgrounds (L, 320, 240, 3) uint8 RGB: the frame folder's own
    ``background_<i>.png`` when it has them, else the shared ``directory/background_<i>.png``, else None.
    The folder listing and frames.json are checked at the call (InputError); each frame folder as it is read
    (InputError naming it, also when its number of sensors differs from the first frame's).
    """
    directory = Path(directory)
    frames = sequence_dir_frames(directory)
    stamps = _read_frames_json(directory, frames)
    gaps = [(int(a.name) + 1, int(b.name) - 1) for a, b in zip(frames, frames[1:]) if int(b.name) > int(a.name) + 1]
    if gaps:
        listing = ", ".join(f"{first:06d}" if first == last else f"{first:06d}-{last:06d}" for first, last in gaps)
        missing = sum(last - first + 1 for first, last in gaps)
        warnings.warn(f"{directory}: frame folders {listing} missing ({missing} frames): each folder is taken as "
                      "the next frame, and the tracker counts frames, not seconds (track.redetect_every)",
                      SequenceGapWarning, stacklevel=2)
    return _iter_frames(directory, frames, stamps)


class SequenceGapWarning(UserWarning):
    """A sequence folder whose frame numbers skip some (``iter_sequence_dir``)."""


def _iter_frames(directory: Path, frames: list[Path], stamps: list[float | None]) -> Iterator[SequenceFrame]:
    n_sensors: int | None = None
    shared: np.ndarray | None = None
    for frame_dir, stamp in zip(frames, stamps):
        T, images = read_scene_dir(frame_dir)
        if n_sensors is None:
            n_sensors = len(T)
            shared = read_scene_backgrounds(directory, n_sensors)
        elif len(T) != n_sensors:
            raise InputError(f"{frame_dir}: {len(T)} sensors, but the sequence's first frame {frames[0].name} has "
                             f"{n_sensors}")
        own = read_scene_backgrounds(frame_dir, n_sensors)
        yield int(frame_dir.name), stamp, T, images, own if own is not None else shared
