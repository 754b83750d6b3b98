"""BOP challenge result files: the CSV of bop_toolkit's ``save_bop_results`` (the "bop19" format).

One header line ``scene_id,im_id,obj_id,score,R,t,time``, then one line per pose estimate:

- ``scene_id``, ``im_id``, ``obj_id``: non-negative integers (the BOP dataset's scene, image and object ids);
- ``score``: a finite number (higher is more confident);
- ``R``: the rotation of T_camera_object, 9 numbers in row-major order separated by single spaces;
- ``t``: its translation, 3 numbers in MILLIMETRES separated by single spaces;
- ``time``: the wall-clock seconds spent on the whole image, the same for every estimate of one image; -1 when
  unknown.

Here (``BopRow``) a pose is a 4x4 float64 matrix in metres, as everywhere in tactile6d: the conversion to and from
millimetres happens only in the file. Numbers are written at full float precision (Python's shortest repr).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import is_rotation, make_pose
from tactile6d.data.hdf5 import write_text

BOP_HEADER = "scene_id,im_id,obj_id,score,R,t,time"
ROTATION_TOL = 1e-4  # max |R^T R - I| entry and |det R - 1| of a file's R
UNKNOWN_TIME = -1.0

# The BOP YCB-V dataset's object ids (its models/models_info.json), keyed by the YCB object names of the data
# directory (ycb/<name>).
YCBV_OBJ_IDS: dict[str, int] = {
    "002_master_chef_can": 1,
    "003_cracker_box": 2,
    "004_sugar_box": 3,
    "005_tomato_soup_can": 4,
    "006_mustard_bottle": 5,
    "007_tuna_fish_can": 6,
    "008_pudding_box": 7,
    "009_gelatin_box": 8,
    "010_potted_meat_can": 9,
    "011_banana": 10,
    "019_pitcher_base": 11,
    "021_bleach_cleanser": 12,
    "024_bowl": 13,
    "025_mug": 14,
    "035_power_drill": 15,
    "036_wood_block": 16,
    "037_scissors": 17,
    "040_large_marker": 18,
    "051_large_clamp": 19,
    "052_extra_large_clamp": 20,
    "061_foam_brick": 21,
}


@dataclass
class BopRow:
    """One pose estimate of a BOP result file. ``T``: (4, 4) float64 T_camera_object in METRES (the file's
    translation is in millimetres); ``time``: seconds spent on the image, -1 when unknown."""

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    T: np.ndarray
    time: float = UNKNOWN_TIME


def object_name_to_bop_id(name: str, explicit_id: int | None = None) -> int:
    """The BOP object id of an object: ``explicit_id`` when given (it wins over the table), else the YCB-V id of a
    YCB name (``YCBV_OBJ_IDS``). InputError when the name is not a YCB-V object and no id is given."""
    if explicit_id is not None:
        if isinstance(explicit_id, bool) or not isinstance(explicit_id, (int, np.integer)) or explicit_id < 0:
            raise InputError(f"BOP object id {explicit_id!r} for object {name!r}: must be a non-negative integer")
        return int(explicit_id)
    if name not in YCBV_OBJ_IDS:
        raise InputError(f"object {name!r} is not one of the 21 BOP YCB-V objects ({', '.join(YCBV_OBJ_IDS)}); "
                         f"pass its BOP obj_id explicitly (the id in your dataset's models/models_info.json)")
    return YCBV_OBJ_IDS[name]


def _number(value: float) -> str:
    """Shortest text that reads back to the same float64 ("0.1", "-1.0", "1e-05")."""
    return repr(float(value))


def _integer_field(value, what: str, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise InputError(f"{where}: {what} {value!r} is not a non-negative integer")
    return int(value)


def rows_to_csv(rows: Iterable[BopRow]) -> str:
    """BOP result rows -> the CSV text (header included, one line per row, ending with a newline).

    InputError naming the row (0-based) whose ids are not non-negative integers, whose score or time is not finite
    (time: >= 0 or -1), or whose ``T`` is not a finite (4, 4) rigid transform (leave failed estimates out).
    """
    lines = [BOP_HEADER]
    for k, row in enumerate(rows):
        where = f"BOP row {k}"
        ids = [_integer_field(getattr(row, f), f, where) for f in ("scene_id", "im_id", "obj_id")]
        T = np.asarray(row.T, dtype=np.float64)
        if T.shape != (4, 4):
            raise InputError(f"{where}: T has shape {T.shape}, not (4, 4)")
        if not (np.all(np.isfinite(T)) and is_rotation(T[:3, :3], atol=ROTATION_TOL)):
            raise InputError(f"{where}: T is not a finite rigid transform (leave failed estimates out of the file)")
        score, time = float(row.score), float(row.time)
        if not math.isfinite(score):
            raise InputError(f"{where}: score {score} is not finite")
        if not (math.isfinite(time) and (time >= 0 or time == UNKNOWN_TIME)):
            raise InputError(f"{where}: time {time} is neither >= 0 seconds nor -1 (unknown)")
        R = " ".join(_number(v) for v in T[:3, :3].reshape(-1))
        t = " ".join(_number(v) for v in T[:3, 3] * 1000.0)
        time_text = "-1" if time == UNKNOWN_TIME else _number(time)
        lines.append(f"{ids[0]},{ids[1]},{ids[2]},{_number(score)},{R},{t},{time_text}")
    return "\n".join(lines) + "\n"


def write_bop_csv(path: str | os.PathLike, rows: Iterable[BopRow]) -> Path:
    """Write BOP result rows to ``path`` (atomically; see ``rows_to_csv``) -> the path."""
    return write_text(path, rows_to_csv(rows))


def _parse_numbers(text: str, count: int, what: str, where: str) -> np.ndarray:
    fields = text.split(" ")
    if len(fields) != count or any(f == "" for f in fields):
        raise InputError(f"{where}: {what} must be {count} numbers separated by single spaces, got {text!r}")
    try:
        values = np.array([float(f) for f in fields])
    except ValueError:
        raise InputError(f"{where}: {what} holds a value that is not a number: {text!r}") from None
    if not np.all(np.isfinite(values)):
        raise InputError(f"{where}: {what} holds NaN or infinite values: {text!r}")
    return values


def _parse_int(text: str, what: str, where: str) -> int:
    if not text.isascii() or not text.isdigit():
        raise InputError(f"{where}: {what} {text!r} is not a non-negative integer")
    return int(text)


def _parse_float(text: str, what: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{where}: {what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"{where}: {what} {text!r} is not finite")
    return value


def csv_to_rows(text: str, source: str = "BOP results") -> list[BopRow]:
    """The text of a BOP result file -> its rows (translations in metres), validating the format.

    Every rule is checked, and the first one broken raises InputError naming ``source`` and the line (1-based):
    the exact header; 7 comma-separated fields per line; integer ids; a finite score; R of 9 numbers forming a
    rotation matrix within ``ROTATION_TOL`` (orthonormal, determinant +1); t of 3 numbers; a time >= 0 or -1, the
    same for every estimate of one (scene_id, im_id). Blank lines are allowed only at the end.
    """
    lines = text.rstrip("\r\n").splitlines()
    if not lines or lines[0].strip() != BOP_HEADER:
        got = lines[0].strip() if lines else ""
        raise InputError(f"{source}: line 1: the header must be {BOP_HEADER!r}, got {got!r}")
    rows: list[BopRow] = []
    image_time: dict[tuple[int, int], tuple[float, int]] = {}
    for number, line in enumerate(lines[1:], start=2):
        where = f"{source}: line {number}"
        fields = line.rstrip("\r").split(",")
        if len(fields) != 7:
            raise InputError(f"{where}: {len(fields)} comma-separated fields, the format has 7 ({BOP_HEADER})")
        scene_id = _parse_int(fields[0].strip(), "scene_id", where)
        im_id = _parse_int(fields[1].strip(), "im_id", where)
        obj_id = _parse_int(fields[2].strip(), "obj_id", where)
        score = _parse_float(fields[3].strip(), "score", where)
        R = _parse_numbers(fields[4].strip(), 9, "R", where).reshape(3, 3)
        if not is_rotation(R, atol=ROTATION_TOL):
            raise InputError(f"{where}: R is not a rotation matrix (orthonormal with determinant +1 within "
                             f"{ROTATION_TOL}); it must be 9 numbers in row-major order")
        t_mm = _parse_numbers(fields[5].strip(), 3, "t", where)
        time = _parse_float(fields[6].strip(), "time", where)
        if time < 0 and time != UNKNOWN_TIME:
            raise InputError(f"{where}: time {time} is neither >= 0 seconds nor -1 (unknown)")
        first = image_time.setdefault((scene_id, im_id), (time, number))
        if first[0] != time:
            raise InputError(f"{where}: time {time} differs from {first[0]} on line {first[1]} for the same image "
                             f"(scene_id {scene_id}, im_id {im_id}); the format has one time per image")
        rows.append(BopRow(scene_id, im_id, obj_id, score, make_pose(R, t_mm / 1000.0), time))
    return rows


def read_bop_csv(path: str | os.PathLike) -> list[BopRow]:
    """Read and validate a BOP result file (``csv_to_rows``) -> its rows, translations in metres. InputError naming
    the file (and the line) when it is missing or breaks a rule of the format."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"BOP result file {path} not found")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: unreadable ({exc})") from exc
    return csv_to_rows(text, source=str(path))
