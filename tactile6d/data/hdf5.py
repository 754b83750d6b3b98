"""HDF5 artifacts: atomic writes, stamped with their schema and config, validated on reading.

Every artifact a stage writes is one HDF5 file whose root attributes say what it is:
``schema`` (a name from ``tactile6d.data.schemas.SCHEMAS``), ``schema_version``, ``config`` (the JSON of the config sections
it was made with), ``tactile6d_version``. Writing goes to a temporary file beside the target and is
renamed into place only once complete, so a crash never leaves a half-written artifact under the real
name. Reading checks the stamp and the datasets the schema requires, and fails with one line that names
the file, what is wrong, and the stage that makes it.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from tactile6d import __version__
from tactile6d.core.errors import ArtifactError
from tactile6d.data.schemas import SCHEMAS, Schema


def get_schema(name: str) -> Schema:
    """The schema called ``name`` (``tactile6d.data.schemas.SCHEMAS``)."""
    if name not in SCHEMAS:
        raise ValueError(f"unknown artifact schema {name!r}")
    return SCHEMAS[name]


def _remake_hint(schema: Schema) -> str:
    return f"it is made by stage '{schema.stage}' (run `dvc repro {schema.stage}`)"


def _file_mode() -> int:
    """The mode ``open`` gives a new file under this process's umask (0o644 under the usual 0o022)."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


# What the atomic writers below give their files: a temporary file is made private (0o600), which the rename
# would keep; the files are results that others in a lab read, as they would read those ``open`` makes.
FILE_MODE = _file_mode()

def write_artifact(
    path: str | os.PathLike,
    schema: str,
    datasets: Mapping[str, Any],
    attrs: Mapping[str, Any] | None = None,
    config: Mapping[str, Any] | None = None,
    compression: str | None = None,
) -> Path:
    """Write an artifact atomically.

    ``datasets`` maps names (``a/b`` makes groups) to arrays; ``attrs`` are extra root attributes
    (JSON-serialisable values); ``config`` is stamped as JSON. ``compression`` ('gzip' or 'lzf')
    applies to arrays of 2 or more dimensions, chunked along the first axis.
    """
    spec = get_schema(schema)
    missing = [name for name in spec.datasets if name not in datasets]
    if missing:
        raise ValueError(f"artifact of schema {schema!r} lacks datasets {missing}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=path.name + ".tmp-", dir=path.parent)
    os.close(fd)
    try:
        with h5py.File(tmp_name, "w") as f:
            f.attrs["schema"] = spec.name
            f.attrs["schema_version"] = spec.version
            f.attrs["tactile6d_version"] = __version__
            f.attrs["config"] = json.dumps(config or {}, sort_keys=True, default=str)
            for key, value in (attrs or {}).items():
                f.attrs[key] = json.dumps(value, default=str)
            for name, value in datasets.items():
                array = np.asarray(value)
                if array.dtype.kind == "U":
                    array = array.astype(h5py.string_dtype())
                kwargs = {}
                if compression and array.ndim >= 2 and array.size > 0:
                    kwargs = {"compression": compression, "chunks": (1,) + array.shape[1:] if array.ndim >= 3 else True}
                f.create_dataset(name, data=array, **kwargs)
        os.chmod(tmp_name, FILE_MODE)
        os.replace(tmp_name, path)
    except BaseException:
        # Nothing may remain under either name when the write did not complete.
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return path


@dataclass
class Artifact:
    """A validated artifact read into memory."""

    path: Path
    schema: str
    config: dict
    attrs: dict
    data: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def __contains__(self, name: str) -> bool:
        return name in self.data


def _read_datasets(group: h5py.Group, prefix: str = "") -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for key, item in group.items():
        name = f"{prefix}{key}"
        if isinstance(item, h5py.Group):
            out.update(_read_datasets(item, name + "/"))
        else:
            value = item[()]
            if item.dtype.kind == "O":
                value = item.asstr()[()]
            out[name] = value
    return out


def read_artifact(path: str | os.PathLike, schema: str) -> Artifact:
    """Read and validate an artifact of the given schema; ArtifactError (one line) if anything is off."""
    spec = get_schema(schema)
    path = Path(path)
    hint = _remake_hint(spec)
    if not path.is_file():
        raise ArtifactError(f"{path}: missing; {hint}")
    try:
        with h5py.File(path, "r") as f:
            found = f.attrs.get("schema")
            if found is None:
                raise ArtifactError(f"{path}: not a tactile6d artifact (no schema stamp); {hint}")
            found = found.decode() if isinstance(found, bytes) else str(found)
            if found != spec.name:
                raise ArtifactError(f"{path}: schema is {found!r} but {spec.name!r} was expected; {hint}")
            version = int(f.attrs.get("schema_version", -1))
            if version != spec.version:
                raise ArtifactError(
                    f"{path}: schema {spec.name!r} version {version}, this code reads version {spec.version}; {hint}"
                )
            missing = [name for name in spec.datasets if name not in f]
            if missing:
                raise ArtifactError(f"{path}: datasets {missing} missing; {hint}")
            data = _read_datasets(f)
            config = json.loads(f.attrs.get("config", "{}"))
            attrs = {
                k: json.loads(v)
                for k, v in f.attrs.items()
                if k not in ("schema", "schema_version", "config", "tactile6d_version")
            }
    except ArtifactError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise ArtifactError(f"{path}: unreadable or corrupt HDF5 ({' '.join(str(exc).split())}); {hint}") from exc
    return Artifact(path=path, schema=spec.name, config=config, attrs=attrs, data=data)


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write JSON atomically (metrics files that DVC reads)."""
    return write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=float) + "\n")


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write a text file atomically (temporary file beside it, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=path.name + ".tmp-", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp_name, FILE_MODE)
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return path


# --- tactile images and scene folders in the paper's triplet layout ---------------------------------

TACTILE_IMAGE_SHAPE = (320, 240, 3)  # rows (sensor z) x columns (sensor y) x RGB


class ImageSizeWarning(UserWarning):
    """A tactile or no-contact image given at another size than the DIGIT's 240 x 320 was read resized to it
    (``to_tactile_size``); name, width and height say which and from what, for a caller that tells several at once."""

    def __init__(self, name: str, width: int, height: int):
        self.name, self.width, self.height = name, int(width), int(height)
        super().__init__(f"{name} is {self.size_text()}")

    def size_text(self) -> str:
        """'W wide x H high: read resized to ...', what the warning says of any image of its size."""
        how = ("averaged down" if self.height > TACTILE_IMAGE_SHAPE[0]
               else "enlarged, bilinear: less detail than a 240 x 320 image")
        return f"{self.width} wide x {self.height} high: read resized to the DIGIT's 240 x 320 ({how})"


def tactile_shape_problem(shape: tuple[int, ...], name: str) -> str | None:
    """An image's shape -> None if it is a DIGIT image's (320, 240, 3), else the sentence that says what is wrong.

    A DIGIT camera's raw frame is 320 wide x 240 high; digit-interface's ``Digit.get_frame()`` turns it into
    the 240 x 320 image this project reads (a transpose and a vertical flip: ``np.rot90(frame)``), so a
    rotated size gets that hint.
    """
    shape = tuple(int(n) for n in shape)
    if shape == TACTILE_IMAGE_SHAPE:
        return None
    size = f"{name} is {shape[1]} wide x {shape[0]} high" if len(shape) >= 2 else f"{name} has shape {shape}"
    problem = f"{size}, a DIGIT image is 240 wide x 320 high (array shape (320, 240, 3))"
    if _looks_turned(shape):
        problem += (": it looks rotated by 90 degrees, as the camera's raw frame is; digit-interface's "
                    "Digit.get_frame() returns np.rot90(frame), which is the image to pass")
    elif len(shape) == 3 and shape[:2] == TACTILE_IMAGE_SHAPE[:2]:
        problem += f": it has {shape[2]} channels, a DIGIT image has 3 (RGB)"
    elif len(shape) == 2 and shape == TACTILE_IMAGE_SHAPE[:2]:
        problem += ": it has one channel, a DIGIT image has 3 (RGB)"
    return problem


def _looks_turned(shape: tuple[int, ...]) -> bool:
    """Whether ``shape`` is (H, W, 3) with W:H = 4:3, a DIGIT image's proportions turned by 90 degrees (the raw frame's)."""
    return len(shape) == 3 and shape[2] == 3 and shape[1] * 3 == shape[0] * 4


def resizable_to_tactile(shape: tuple[int, ...]) -> bool:
    """Whether an image of ``shape`` is a DIGIT image at another resolution: (H, W, 3), H:W = 4:3 as (320, 240, 3)'s,
    but not that size (a DIGIT streamed at VGA gives 640 x 480 once turned; TACTO renders 160 x 120 by default)."""
    shape = tuple(int(n) for n in shape)
    return (len(shape) == 3 and shape[2] == 3 and shape[0] * 3 == shape[1] * 4 and shape[0] >= 4
            and shape != TACTILE_IMAGE_SHAPE)


def resize_to_tactile(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 with H:W = 4:3 (``resizable_to_tactile``) -> (320, 240, 3) uint8: each output pixel the mean of
    the pixels it covers when shrinking (OpenCV's INTER_AREA: a 2 x 2 mean from 640 x 480), bilinear when enlarging.
    The same field of view at another resolution, so the gel's millimetres per pixel come out as the DIGIT's."""
    import cv2

    image = np.ascontiguousarray(image)
    shrink = image.shape[0] > TACTILE_IMAGE_SHAPE[0]
    return cv2.resize(image, TACTILE_IMAGE_SHAPE[1::-1], interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def tactile_size_problem(shape: tuple[int, ...], name: str) -> str | None:
    """``tactile_shape_problem``, but None for another size of the DIGIT image's proportions
    (``resizable_to_tactile``), which ``to_tactile_size`` resizes; the sentence says so where it applies."""
    shape = tuple(int(n) for n in shape)
    if resizable_to_tactile(shape):
        return None
    problem = tactile_shape_problem(shape, name)
    if problem is not None and len(shape) == 3 and shape[2] == 3 and not _looks_turned(shape):
        problem += "; an image of its proportions at another size (e.g. 480 wide x 640 high) is read resized"
    return problem


def to_tactile_size(image: np.ndarray, name: str) -> np.ndarray:
    """An image -> (320, 240, 3): as it is at the DIGIT's size, resized (``resize_to_tactile``) with an
    ``ImageSizeWarning`` at another size of its proportions; InputError naming it otherwise."""
    from tactile6d.core.errors import InputError

    problem = tactile_size_problem(image.shape, name)
    if problem is not None:
        raise InputError(problem)
    return sized_as_tactile(image, name)


def sized_as_tactile(image: np.ndarray, name: str) -> np.ndarray:
    """An image whose shape ``tactile_size_problem`` passed -> (320, 240, 3): as it is at the DIGIT's size, else
    resized (``resize_to_tactile``) with an ``ImageSizeWarning`` naming it. For a caller that checked the shape
    itself, before other checks of its own (``perception.inputs``); ``to_tactile_size`` checks and resizes."""
    import warnings

    if image.shape == TACTILE_IMAGE_SHAPE:
        return image
    warnings.warn(ImageSizeWarning(name, image.shape[1], image.shape[0]), stacklevel=3)
    return resize_to_tactile(image)


def read_tactile_image(path: str | os.PathLike) -> np.ndarray:
    """A DIGIT image file -> (320, 240, 3) uint8 RGB, resized from another size of its proportions
    (``to_tactile_size``). InputError if unreadable or of other proportions."""
    import cv2

    from tactile6d.core.errors import InputError

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    return to_tactile_size(cv2.cvtColor(image, cv2.COLOR_BGR2RGB), str(path))


def write_tactile_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """(320, 240, 3) uint8 RGB -> PNG file."""
    import cv2

    cv2.imwrite(str(path), cv2.cvtColor(np.asarray(image, dtype=np.uint8), cv2.COLOR_RGB2BGR))


def read_scene_dir(directory: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """A scene folder in the paper's triplet layout -> T_world_sensors (L, 4, 4), images (L, 320, 240, 3).

    The folder holds ``poses_sensors.txt`` (one ``x y z ax ay az angle`` line per sensor) and
    ``Image_heatmap_<i>.png`` for i = 0..L-1 (or ``.jpg``/``.jpeg`` where the PNG is absent:
    ``scene_image_file``; and, optionally, the sensors' no-contact images: ``read_scene_backgrounds``). InputError
    names what is missing or inconsistent.
    """
    from tactile6d.core.errors import InputError
    from tactile6d.core.geometry import text_to_poses

    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"scene folder {directory} not found")
    pose_file = directory / "poses_sensors.txt"
    if not pose_file.is_file():
        raise InputError(f"{directory}: poses_sensors.txt missing")
    try:
        poses = text_to_poses(pose_file.read_text())
    except ValueError as exc:
        raise InputError(f"{pose_file}: {exc}") from exc
    n_images = len({p.stem for p in directory.iterdir() if SCENE_IMAGE.fullmatch(p.name)})
    expected = [scene_image_file(directory, f"Image_heatmap_{i}") for i in range(len(poses))]
    missing = [f"Image_heatmap_{i}.png" for i, p in enumerate(expected) if p is None]
    if missing:
        raise InputError(f"{directory}: {len(poses)} sensor poses but image(s) {', '.join(missing)} missing")
    if n_images != len(poses):
        raise InputError(f"{directory}: {n_images} images but {len(poses)} sensor poses")
    return poses, np.stack([read_tactile_image(p) for p in expected])


SCENE_BACKGROUND = "background_{}.png"  # sensor i's own no-contact image in a scene folder, as written
# A scene folder's images are PNG files, as the paper's are; JPEG files (as a camera or another tool saves them) are
# read where the PNG is absent.
SCENE_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
SCENE_IMAGE = re.compile(r"Image_heatmap_\d+\.(png|jpg|jpeg)")


def scene_image_file(directory: Path, stem: str) -> Path | None:
    """The image file ``stem`` in a scene folder, PNG or JPEG (``SCENE_IMAGE_SUFFIXES``) -> its path, or None when
    there is none; InputError when there are several (two files for one image: which is meant is not said)."""
    from tactile6d.core.errors import InputError

    found = [directory / (stem + suffix) for suffix in SCENE_IMAGE_SUFFIXES if (directory / (stem + suffix)).is_file()]
    if len(found) > 1:
        raise InputError(f"{directory}: {' and '.join(p.name for p in found)} are both there; keep one image per file "
                         "name")
    return found[0] if found else None


def read_background_images(paths: list[str | os.PathLike]) -> np.ndarray:
    """No-contact image files -> (320, 240, 3) uint8 RGB for one file (every sensor's), or
    (L, 320, 240, 3) for L files (one per sensor, in sensor order). InputError naming the file that is
    missing or unreadable."""
    from tactile6d.core.errors import InputError

    if len(paths) == 0:
        raise InputError("no background image file given")
    images = []
    for path in paths:
        if not Path(path).is_file():
            raise InputError(f"background {path} not found")
        try:
            images.append(read_tactile_image(path))
        except InputError as exc:
            raise InputError(f"background {exc}") from exc
    return images[0] if len(images) == 1 else np.stack(images)


def read_scene_backgrounds(directory: str | os.PathLike, n_sensors: int) -> np.ndarray | None:
    """The sensors' own no-contact images of a scene folder, ``background_<i>.png`` (or JPEG) for i = 0..L-1 beside
    ``Image_heatmap_<i>.png`` -> (L, 320, 240, 3) uint8 RGB, or None when the folder holds none.
    InputError when only some sensors have one (naming the missing ones) or one is unreadable."""
    from tactile6d.core.errors import InputError

    directory = Path(directory)
    expected = [scene_image_file(directory, Path(SCENE_BACKGROUND.format(i)).stem) for i in range(n_sensors)]
    present = [p is not None for p in expected]
    if not any(present):
        return None
    if not all(present):
        missing = ", ".join(SCENE_BACKGROUND.format(i) for i, here in enumerate(present) if not here)
        raise InputError(f"{directory}: {sum(present)} of {n_sensors} sensors have a no-contact image "
                         f"background_<i>.png; {missing} missing (give every sensor's, or none)")
    return read_background_images(expected)[None] if n_sensors == 1 else read_background_images(expected)
