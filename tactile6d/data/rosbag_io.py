"""ROS 2 bags in and out, without a ROS install (the pure-Python ``rosbags`` library, ROS 2 Humble message types).

Reading (``read_bag_frames``): the DIGIT images of L sensors, one ``sensor_msgs/msg/Image`` (rgb8 or bgr8) or
``sensor_msgs/msg/CompressedImage`` (png, jpeg) topic per sensor, grouped into frames, with each sensor's pose either
fixed or looked up in the bag's TF tree (``/tf``, ``/tf_static``). Writing: a synthetic or converted sequence
(``write_sequence_bag``) and a tracker's object poses as ``geometry_msgs/msg/PoseStamped`` (``write_pose_bag``, read
back by ``read_pose_bag``).

Conventions: a bag is a rosbag2 folder (``metadata.yaml`` and its storage files, sqlite3 ``.db3`` or ``.mcap``) or a
single ``.mcap`` / ``.db3`` file, which is then read alone. Times are float seconds from a message's
``header.stamp`` (sec + nanosec 1e-9); a zero (unset) header stamp falls back to the bag's log time of the message.
Written messages get the log time of their header stamp, in nanoseconds. ROS quaternions are ``(x, y, z, w)``.
Poses are 4x4 float64 ``T_a_b`` in metres; images (320, 240, 3) uint8 RGB (320 rows x 240 columns).
"""

from __future__ import annotations

import contextlib
import heapq
import math
import os
import shutil
import warnings
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import invert_pose, is_rotation, make_pose, quaternion_to_rotmat
from tactile6d.data.hdf5 import TACTILE_IMAGE_SHAPE, tactile_size_problem, to_tactile_size

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF_TOPICS = ("/tf", "/tf_static")
STATIC_TF_TOPIC = "/tf_static"
POSE_TOPIC = "/tactile6d/object_pose"
STORAGES = ("mcap", "sqlite3")
BAG_VERSION = 8  # rosbag2 metadata version written (the oldest rosbags writes; 9 only changed the QoS format)


class BagFrame(NamedTuple):
    """One frame of a bag: ``stamp`` seconds (the first image topic's header stamp), ``T_world_sensors`` (L, 4, 4)
    metres, ``images`` (L, 320, 240, 3) uint8 RGB, in the order of the image topics."""

    stamp: float
    T_world_sensors: np.ndarray
    images: np.ndarray


class SkippedFramesWarning(UserWarning):
    """Frames of a bag left out because some sensor had no image within the synchronisation tolerance."""


# --- small conversions ---------------------------------------------------------------------------------------


def rotmat_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation -> (..., 4) unit quaternion ``(x, y, z, w)`` (ROS order) with w >= 0.

    Shepperd's method: the largest of 4w^2, 4x^2, 4y^2, 4z^2 is taken from the diagonal, and the other components from
    the off-diagonal sums and differences divided by it. Inverse of ``tactile6d.core.geometry.quaternion_to_rotmat``.
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # 4 * (w^2, x^2, y^2, z^2), each written as 1 + a sum of diagonal entries.
    squares = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    k = np.argmax(squares, axis=-1)
    big = np.sqrt(np.maximum(np.take_along_axis(squares, k[..., None], -1)[..., 0], 1e-300))  # 2 |component k|
    # Rows: the candidates (x, y, z, w) * 2 * big, for k = w, x, y, z.
    candidates = np.stack(
        [
            np.stack([m21 - m12, m02 - m20, m10 - m01, big * big], -1),
            np.stack([big * big, m01 + m10, m02 + m20, m21 - m12], -1),
            np.stack([m01 + m10, big * big, m12 + m21, m02 - m20], -1),
            np.stack([m02 + m20, m12 + m21, big * big, m10 - m01], -1),
        ],
        axis=-2,
    )
    q = np.take_along_axis(candidates, k[..., None, None], -2)[..., 0, :] / (2.0 * big[..., None])
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def seconds_to_stamp(seconds: float) -> tuple[int, int]:
    """Float seconds (>= 0) -> ROS ``(sec, nanosec)``, rounded to the nearest nanosecond."""
    total = int(round(float(seconds) * 1e9))
    return total // 1_000_000_000, total % 1_000_000_000


def stamp_to_seconds(sec: int, nanosec: int) -> float:
    """ROS ``(sec, nanosec)`` -> float seconds."""
    return int(sec) + int(nanosec) * 1e-9


def _header_seconds(header, log_time_ns: int) -> float:
    """A header's stamp in seconds; the log time when the stamp is zero (not set by the publisher)."""
    if header.stamp.sec == 0 and header.stamp.nanosec == 0:
        return log_time_ns * 1e-9
    return stamp_to_seconds(header.stamp.sec, header.stamp.nanosec)


def _frame_id(name: str) -> str:
    """A TF frame id without ROS 1's leading slash ("/world" and "world" are the same frame)."""
    return name.lstrip("/")


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


# --- opening a bag --------------------------------------------------------------------------------------------


def _bag_source(path: str | os.PathLike) -> Path:
    """What to give rosbags' Reader for ``path``: a bag folder (with metadata.yaml), or a lone .mcap / .db3 file
    (also the only one in a folder without metadata.yaml). InputError naming the path otherwise."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"ROS 2 bag {path} not found")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return path
        files = sorted([*path.glob("*.mcap"), *path.glob("*.db3")])
        if len(files) == 1:
            return files[0]
        raise InputError(f"{path}: not a ROS 2 bag folder (no metadata.yaml, and {len(files)} .mcap/.db3 files)")
    if path.name == "metadata.yaml":
        return path.parent
    if path.suffix in (".mcap", ".db3"):
        return path
    if path.suffix == ".bag":
        raise InputError(f"{path}: a ROS 1 bag; convert it to ROS 2 first: rosbags-convert --src {path} --dst <folder>")
    raise InputError(f"{path}: not a ROS 2 bag (a folder with metadata.yaml, or an .mcap or .db3 file)")


@contextlib.contextmanager
def _open_reader(path: str | os.PathLike):
    """``with _open_reader(path) as reader``: an open rosbags Reader of the bag at ``path``, closed at the end."""
    from rosbags.rosbag2 import Reader

    source = _bag_source(path)
    try:
        reader = Reader(source)
        reader.open()
    except Exception as exc:  # rosbags' ReaderError, sqlite3/mcap errors of a corrupt file
        raise InputError(f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})") from exc
    try:
        yield reader
    finally:
        reader.close()


def _topic_connections(reader, path, topics: Sequence[str], types: Sequence[str]) -> dict[str, list]:
    """topic -> its connections, for each of ``topics``; InputError listing the bag's topics when one is missing, or
    naming the topic whose message type is not one of ``types``."""
    available = reader.topics
    missing = [t for t in topics if t not in available]
    if missing:
        listing = ", ".join(f"{t} ({info.msgtype})" for t, info in sorted(available.items())) or "none"
        raise InputError(f"{path}: topic(s) {', '.join(missing)} not in the bag; its topics: {listing}")
    out = {}
    for topic in topics:
        conns = available[topic].connections
        wrong = sorted({c.msgtype for c in conns} - set(types))
        if wrong:
            raise InputError(f"{path}: topic {topic} carries {', '.join(wrong)}, expected {' or '.join(types)}")
        out[topic] = conns
    return out


# --- images ---------------------------------------------------------------------------------------------------


RAW_FRAME_SHAPE = (TACTILE_IMAGE_SHAPE[1], TACTILE_IMAGE_SHAPE[0])  # the camera's frame: 240 rows x 320 columns


def _check_digit_shape(rows: int, cols: int, topic: str, raw_camera_frames: bool) -> None:
    """InputError naming the topic unless (rows, cols) is a DIGIT image's, at its own size or another of its
    proportions (``hdf5.tactile_size_problem``; a raw frame's turned, with ``raw_camera_frames``)."""
    if raw_camera_frames:
        if tactile_size_problem((cols, rows, 3), "") is not None:
            raise InputError(f"{topic}: an image is {cols} wide x {rows} high; a DIGIT camera's raw frame "
                             f"(--raw-camera-frames) is {RAW_FRAME_SHAPE[1]} wide x {RAW_FRAME_SHAPE[0]} high (or "
                             "another size of its proportions, 4:3, read resized)")
        return
    problem = tactile_size_problem((rows, cols, 3), f"{topic}: an image")
    if problem is not None:
        if tactile_size_problem((cols, rows, 3), "") is None:
            problem += " (tactile6d track --bag: --raw-camera-frames turns them so)"
        raise InputError(problem)


def image_from_message(msg, topic: str, raw_camera_frames: bool = False) -> np.ndarray:
    """A deserialised ``sensor_msgs/msg/Image`` (encoding rgb8 or bgr8) or ``CompressedImage`` (png, jpeg) ->
    (320, 240, 3) uint8 RGB (a copy). With ``raw_camera_frames`` the message holds the camera's raw frame (240 rows
    x 320 columns), turned as digit-interface's ``Digit.get_frame()`` turns it (``np.rot90``). An image at another
    size of these proportions (a DIGIT streamed at VGA) is resized (``hdf5.to_tactile_size``, an
    ``ImageSizeWarning``). InputError naming the topic for another encoding, an undecodable image or another size."""
    if msg.__msgtype__ == COMPRESSED_IMAGE:
        import cv2

        bgr = cv2.imdecode(np.frombuffer(np.asarray(msg.data, dtype=np.uint8), dtype=np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise InputError(f"{topic}: a CompressedImage (format {msg.format!r}) that OpenCV cannot decode")
        _check_digit_shape(bgr.shape[0], bgr.shape[1], topic, raw_camera_frames)
        image = bgr[..., ::-1]
    else:
        encoding = msg.encoding.lower()
        if encoding not in ("rgb8", "bgr8"):
            raise InputError(f"{topic}: image encoding {msg.encoding!r}, expected rgb8 or bgr8")
        rows, cols, step = int(msg.height), int(msg.width), int(msg.step)
        _check_digit_shape(rows, cols, topic, raw_camera_frames)
        data = np.asarray(msg.data, dtype=np.uint8)
        if step < 3 * cols or data.size < rows * step:
            raise InputError(f"{topic}: image data of {data.size} bytes with step {step} for {cols} x {rows} "
                             f"{encoding}")
        image = data[: rows * step].reshape(rows, step)[:, : 3 * cols].reshape(rows, cols, 3)
        image = image[..., ::-1] if encoding == "bgr8" else image
    image = np.ascontiguousarray(np.rot90(image) if raw_camera_frames else image)
    return to_tactile_size(image, f"{topic}: an image")


# --- the TF tree ----------------------------------------------------------------------------------------------


class _Edge:
    """The transforms T_parent_child of one TF edge over time: ``stamps`` (n,) sorted seconds (static transforms at
    -inf, valid from the start), ``T`` (n, 4, 4)."""

    def __init__(self, parent: str):
        self.parent = parent
        self._items: list[tuple[float, int, np.ndarray]] = []
        self.stamps = np.zeros(0)
        self.T = np.zeros((0, 4, 4))

    def add(self, stamp: float, T: np.ndarray) -> None:
        self._items.append((stamp, len(self._items), T))

    def freeze(self) -> None:
        items = sorted(self._items, key=lambda item: item[:2])  # later-published wins among equal stamps
        self.stamps = np.array([item[0] for item in items])
        self.T = np.stack([item[2] for item in items])

    def _used(self, stamp: float) -> int:
        """The index of the latest transform with a stamp <= ``stamp``; of the earliest one when all are later."""
        return max(int(np.searchsorted(self.stamps, stamp, side="right")) - 1, 0)

    def at(self, stamp: float) -> np.ndarray:
        """The transform in force at ``stamp`` (``_used``)."""
        return self.T[self._used(stamp)]

    def age(self, stamp: float) -> float:
        """How far (seconds) the transform ``at`` gives for ``stamp`` is from it; 0 for a static transform."""
        used = float(self.stamps[self._used(stamp)])
        return 0.0 if used == -math.inf else abs(stamp - used)


def _transform_to_pose(transform) -> np.ndarray:
    q = transform.rotation
    v = transform.translation
    return make_pose(quaternion_to_rotmat(np.array([q.x, q.y, q.z, q.w])), np.array([v.x, v.y, v.z]))


def _read_tf_tree(reader, path, typestore) -> dict[str, _Edge]:
    """child frame -> its edge, from every /tf and /tf_static message of the bag. InputError when there are none, or
    a frame has two parents."""
    conns = [c for c in reader.connections if c.topic in TF_TOPICS and c.msgtype == TF_MESSAGE]
    edges: dict[str, _Edge] = {}
    for conn, log_time, raw in reader.messages(connections=conns) if conns else ():
        static = conn.topic == STATIC_TF_TOPIC
        for ts in typestore.deserialize_cdr(raw, conn.msgtype).transforms:
            parent, child = _frame_id(ts.header.frame_id), _frame_id(ts.child_frame_id)
            edge = edges.setdefault(child, _Edge(parent))
            if edge.parent != parent:
                raise InputError(f"{path}: TF frame {child!r} has two parents, {edge.parent!r} and {parent!r} "
                                 f"(a re-parented frame is not supported)")
            edge.add(-math.inf if static else _header_seconds(ts.header, log_time), _transform_to_pose(ts.transform))
    if not edges:
        raise InputError(f"{path}: no TF transforms (no /tf or /tf_static messages) to place the sensors; "
                         f"give fixed_poses instead")
    for edge in edges.values():
        edge.freeze()
    return edges


def _ancestors(frame: str, edges: dict[str, _Edge], path) -> list[str]:
    """[frame, its parent, ..., the root of its tree]."""
    chain = [frame]
    while chain[-1] in edges:
        parent = edges[chain[-1]].parent
        if parent in chain:
            raise InputError(f"{path}: the TF tree has a loop through frame {parent!r}")
        chain.append(parent)
    return chain


def _chain_plan(world: str, sensor: str, edges: dict[str, _Edge], path) -> tuple[list[str], list[str]]:
    """The edges (named by their child frames) from ``sensor`` and from ``world`` up to their lowest common
    ancestor. InputError naming the frame when it is not in the bag, or when no chain connects the two."""
    known = set(edges) | {e.parent for e in edges.values()}
    for frame, what in ((sensor, "sensor frame"), (world, "world frame")):
        if frame not in known:
            raise InputError(f"{path}: {what} {frame!r} is in no /tf or /tf_static transform; the bag's frames: "
                             f"{', '.join(sorted(known))}")
    up_sensor, up_world = _ancestors(sensor, edges, path), _ancestors(world, edges, path)
    common = next((f for f in up_sensor if f in up_world), None)
    if common is None:
        raise InputError(f"{path}: no chain of TF transforms connects world frame {world!r} (tree root "
                         f"{up_world[-1]!r}) to sensor frame {sensor!r} (tree root {up_sensor[-1]!r})")
    return up_sensor[: up_sensor.index(common)], up_world[: up_world.index(common)]


def _compose(children: list[str], edges: dict[str, _Edge], stamp: float) -> np.ndarray:
    """T_ancestor_frame along the edges from a frame (children[0]) up to an ancestor, at ``stamp``."""
    T = np.eye(4)
    for child in children:
        T = edges[child].at(stamp) @ T
    return T


def _tf_age(plan: tuple[list[str], list[str]], edges: dict[str, _Edge], stamp: float) -> float:
    """The oldest (or, before the first, the farthest ahead) of the transforms one chain plan uses at ``stamp``."""
    return max((edges[child].age(stamp) for child in (*plan[0], *plan[1])), default=0.0)


def _tf_poses_at(plans: list[tuple[list[str], list[str]]], edges: dict[str, _Edge], stamp: float) -> np.ndarray:
    """T_world_sensors (L, 4, 4) at ``stamp`` seconds, one per chain plan (``_chain_plan``)."""
    return np.stack([invert_pose(_compose(up_w, edges, stamp)) @ _compose(up_s, edges, stamp) for up_s, up_w in plans])


# --- reading frames -------------------------------------------------------------------------------------------


# How far (seconds) the first topic may run ahead of a frame before the frame is decided without waiting for the
# other topics' later messages: a sensor that stopped publishing would otherwise hold every later frame (and its
# images) in memory until the bag ends. Recorders write messages within milliseconds of their stamps.
SYNC_HORIZON = 1.0
# How far (seconds) every topic must have run past a frame before it is decided, beyond the synchronisation
# tolerance: messages recorded up to this late (a frame's images after the next frame's) still join their frame.
REORDER_WINDOW = 0.1


class SensorTally:
    """Frames skipped for each sensor's sake: ``count[k]`` of them, the first at stamp ``first[k]`` (None: none)."""

    def __init__(self, n_sensors: int):
        self.count = [0] * n_sensors
        self.first: list[float | None] = [None] * n_sensors

    def add(self, k: int, stamp: float) -> None:
        self.count[k] += 1
        if self.first[k] is None:
            self.first[k] = stamp


class SyncCounts:
    """What ``_synchronise`` left out: ``missing``, the frames where topic k (k >= 1) had no message within the
    tolerance (``SensorTally``), and ``late`` messages of the first topic that came after a later-stamped one had
    been emitted (out of order)."""

    def __init__(self, n_topics: int):
        self.missing = SensorTally(n_topics)
        self.late = 0


def _synchronise(messages: Iterable[tuple[int, float, object]], n_topics: int, tolerance: float,
                 counts: SyncCounts | None = None):
    """Group stamped messages of ``n_topics`` topics into frames driven by topic 0.

    messages: (topic index, stamp seconds, message) in bag order -> yields (stamp, [message per topic]) for each
    message of topic 0, in stamp order, with each other topic's message nearest in stamp, or (stamp, None) when some
    topic has none within ``tolerance``. A frame is emitted once every topic has a message later than its stamp +
    ``REORDER_WINDOW`` (+ tolerance for the others), once topic 0 is ``SYNC_HORIZON`` seconds past it (a topic that
    fell silent), or when the bag ends, so that only a window of messages is held. A topic-0 message stamped before
    one already emitted (recorded out of order, later than the window) is left out. ``counts`` (``SyncCounts``) is
    filled with what was left out.
    """
    counts = counts if counts is not None else SyncCounts(n_topics)
    pending: list = []  # a heap of (stamp, arrival, message) of topic 0
    buffers = [deque() for _ in range(n_topics)]
    latest = [-math.inf] * n_topics
    emitted = -math.inf
    arrivals = 0

    def emit(stamp, first):
        chosen = [first]
        for k, buffer in enumerate(buffers[1:], start=1):
            best = min(buffer, key=lambda item: abs(item[0] - stamp), default=None)
            if best is None or abs(best[0] - stamp) > tolerance:
                counts.missing.add(k, stamp)
                chosen = None
            elif chosen is not None:
                chosen.append(best[1])
        for buffer in buffers[1:]:
            while buffer and buffer[0][0] < stamp - tolerance:
                buffer.popleft()
        return stamp, chosen

    def ready(stamp):
        if latest[0] > stamp + SYNC_HORIZON:
            return True
        return latest[0] > stamp + REORDER_WINDOW and all(latest[j] > stamp + tolerance + REORDER_WINDOW
                                                           for j in range(1, n_topics))

    for k, stamp, msg in messages:
        if k == 0:
            if stamp <= emitted:
                counts.late += 1
                continue
            heapq.heappush(pending, (stamp, arrivals, msg))
            arrivals += 1
        else:
            buffers[k].append((stamp, msg))
        latest[k] = max(latest[k], stamp)
        while pending and ready(pending[0][0]):
            stamp0, _, first = heapq.heappop(pending)
            emitted = stamp0
            yield emit(stamp0, first)
    while pending:
        stamp0, _, first = heapq.heappop(pending)
        yield emit(stamp0, first)


def read_bag_frames(
    path: str | os.PathLike,
    image_topics: list[str],
    sensor_frames: list[str] | None = None,
    world_frame: str = "world",
    fixed_poses: np.ndarray | None = None,
    sync_tolerance: float = 0.02,
    tf_tolerance: float = 0.25,
    raw_camera_frames: bool = False,
) -> Iterator[BagFrame]:
    """The frames of L DIGIT sensors recorded in a ROS 2 bag, read lazily -> an iterator of ``BagFrame``.

    image_topics: one topic per sensor (``sensor_msgs/msg/Image`` rgb8/bgr8, or ``CompressedImage`` png/jpeg), each
    image 240 wide x 320 high, or with ``raw_camera_frames`` the camera's raw frame (``image_from_message``).
    Frames are driven by the FIRST topic's messages, in header-stamp order: each other topic contributes its message
    nearest in header stamp, if within ``sync_tolerance`` seconds; a frame where some sensor has none is skipped, as
    is a first-topic message recorded after a later-stamped one had been read (out of order), and what was skipped is
    reported once the bag is read, naming the sensors (``SkippedFramesWarning``). A sensor that stops publishing
    holds up no more than ``SYNC_HORIZON`` seconds of frames.

    Sensor poses T_world_sensors (L, 4, 4), metres: exactly one of
    - ``fixed_poses`` (L, 4, 4): the same for every frame;
    - ``sensor_frames``: one TF frame per topic, looked up in the bag's /tf and /tf_static: for each frame, the chain
      ``world_frame`` -> ... -> sensor frame composed from, per edge, the latest transform stamped at or before the
      frame's stamp (no interpolation; /tf_static transforms hold from the start). An edge whose transforms all come
      after a frame's stamp (recording started before TF was published) uses its earliest one for that frame. A
      frame whose chain for some sensor uses a transform more than ``tf_tolerance`` seconds from its stamp (TF that
      stopped, or has not started) is skipped, as tf2 refuses to extrapolate.

    The bag, its topics and the TF chains are checked at the call (InputError naming the topic or frame, listing what
    the bag has); images as they are read (InputError naming the topic: encoding, size, a rotated camera).
    """
    image_topics = list(image_topics)
    if not image_topics:
        raise InputError("no image topics given (one per sensor)")
    if len(set(image_topics)) != len(image_topics):
        raise InputError(f"an image topic is given twice in {image_topics} (one per sensor)")
    if (sensor_frames is None) == (fixed_poses is None):
        raise InputError("give the sensor poses one way: TF frames, one per image topic (--frames), or fixed poses "
                         "(--poses)")
    if not (math.isfinite(sync_tolerance) and sync_tolerance >= 0):
        raise InputError(f"the synchronisation tolerance {sync_tolerance} must be >= 0 seconds")
    if not (math.isfinite(tf_tolerance) and tf_tolerance >= 0):
        raise InputError(f"the TF tolerance {tf_tolerance} must be >= 0 seconds")
    n_sensors = len(image_topics)
    if fixed_poses is not None:
        fixed_poses = np.asarray(fixed_poses, dtype=np.float64)
        if fixed_poses.shape != (n_sensors, 4, 4):
            raise InputError(f"{len(fixed_poses)} fixed sensor poses (--poses) for {n_sensors} image topics (one "
                             f"each, in the order of the topics)")
        if not (np.all(np.isfinite(fixed_poses)) and np.all(is_rotation(fixed_poses[:, :3, :3]))):
            raise InputError("the fixed sensor poses (--poses) are not finite rigid transforms")
    else:
        sensor_frames = [_frame_id(f) for f in sensor_frames]
        if len(sensor_frames) != n_sensors:
            raise InputError(f"{len(sensor_frames)} sensor TF frames (--frames) for {n_sensors} image topics (one "
                             f"each, in the order of the topics)")
    typestore = _typestore()
    with _open_reader(path) as reader:
        _topic_connections(reader, path, image_topics, (IMAGE, COMPRESSED_IMAGE))
        edges, plans = {}, []
        if sensor_frames is not None:
            edges = _read_tf_tree(reader, path, typestore)
            plans = [_chain_plan(_frame_id(world_frame), f, edges, path) for f in sensor_frames]
    return _iter_bag_frames(path, image_topics, typestore, sync_tolerance, fixed_poses, edges, plans,
                            sensor_frames, tf_tolerance, raw_camera_frames)


def _iter_bag_frames(path, image_topics, typestore, tolerance, fixed_poses, edges, plans, sensor_frames,
                     tf_tolerance, raw_camera_frames) -> Iterator[BagFrame]:
    index = {topic: k for k, topic in enumerate(image_topics)}
    counts = SyncCounts(len(image_topics))
    stale = SensorTally(len(image_topics))  # frames whose TF chain for the sensor was too old
    read = total = 0
    with _open_reader(path) as reader:
        conns = [c for topic in image_topics for c in reader.topics[topic].connections]

        def stamped():
            for conn, log_time, raw in reader.messages(connections=conns):
                msg = typestore.deserialize_cdr(raw, conn.msgtype)
                yield index[conn.topic], _header_seconds(msg.header, log_time), msg

        for stamp, chosen in _synchronise(stamped(), len(image_topics), tolerance, counts):
            total += 1
            if chosen is None:
                continue
            if plans:
                ages = [_tf_age(plan, edges, stamp) for plan in plans]
                if max(ages) > tf_tolerance:
                    for k, age in enumerate(ages):
                        if age > tf_tolerance:
                            stale.add(k, stamp)
                    continue
            images = np.stack([image_from_message(msg, image_topics[k], raw_camera_frames)
                               for k, msg in enumerate(chosen)])
            T = fixed_poses.copy() if fixed_poses is not None else _tf_poses_at(plans, edges, stamp)
            read += 1
            yield BagFrame(stamp, T, images)
    missing = counts.missing
    reasons = [f"sensor {k} ({image_topics[k]}) had no image within {tolerance} s of the first topic's in "
               f"{missing.count[k]}, from {missing.first[k]:.3f} s on"
               for k in range(1, len(image_topics)) if missing.count[k]]
    reasons += [f"sensor {k}'s TF chain (frame {sensor_frames[k]!r}) was more than {tf_tolerance} s from the frame's "
                f"stamp in {stale.count[k]}, from {stale.first[k]:.3f} s on (TF stopped or not yet published)"
                for k in range(len(image_topics)) if stale.count[k]]
    if counts.late:
        reasons.append(f"{counts.late} images of the first topic ({image_topics[0]}) came out of order, after a "
                       "later-stamped one, and were left out")
    if reasons:
        skipped = total + counts.late - read
        warnings.warn(f"{path}: {skipped} of {total + counts.late} frames skipped: " + "; ".join(reasons),
                      SkippedFramesWarning, stacklevel=2)


# --- writing --------------------------------------------------------------------------------------------------


def _new_writer(path: str | os.PathLike, storage: str):
    """A rosbags Writer of a new bag folder at ``path``, to open with ``with``. InputError when the path exists or the
    storage is unknown."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    if storage not in plugins:
        raise InputError(f"bag storage {storage!r}: expected one of {', '.join(STORAGES)}")
    if Path(path).exists():
        raise InputError(f"{path}: exists already; a bag is written to a new folder")
    return Writer(path, version=BAG_VERSION, storage_plugin=plugins[storage])


def _check_stamps(stamps: np.ndarray, n_frames: int, path) -> np.ndarray:
    stamps = np.asarray(stamps, dtype=np.float64)
    if stamps.shape != (n_frames,):
        raise InputError(f"{path}: {stamps.shape} stamps for {n_frames} frames (one each)")
    bad = np.flatnonzero(~np.isfinite(stamps) | (stamps < 0))
    if len(bad):
        raise InputError(f"{path}: stamps must be finite seconds >= 0 (ROS time), got {stamps[bad[0]]} for frame "
                         f"{bad[0]}")
    return stamps


def _header(typestore, seconds: float, frame_id: str):
    Header, Time = typestore.types["std_msgs/msg/Header"], typestore.types["builtin_interfaces/msg/Time"]
    sec, nanosec = seconds_to_stamp(seconds)
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _log_time(seconds: float) -> int:
    sec, nanosec = seconds_to_stamp(seconds)
    return sec * 1_000_000_000 + nanosec


def pose_to_transform_msg(typestore, T: np.ndarray):
    """(4, 4) pose -> a ``geometry_msgs/msg/Transform`` of ``typestore``."""
    types = typestore.types
    x, y, z, w = rotmat_to_quaternion(np.asarray(T)[:3, :3])
    t = np.asarray(T, dtype=np.float64)[:3, 3]
    return types["geometry_msgs/msg/Transform"](
        translation=types["geometry_msgs/msg/Vector3"](x=float(t[0]), y=float(t[1]), z=float(t[2])),
        rotation=types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w)),
    )


def tf_message(typestore, seconds: float, parents: Sequence[str], children: Sequence[str], T_parent_children):
    """A ``tf2_msgs/msg/TFMessage`` stamped ``seconds`` with one transform T_parent_child (4, 4) per
    (parent, child, pose) of ``parents``, ``children`` and ``T_parent_children`` (n, 4, 4)."""
    types = typestore.types
    transforms = [
        types["geometry_msgs/msg/TransformStamped"](
            header=_header(typestore, seconds, parent),
            child_frame_id=child,
            transform=pose_to_transform_msg(typestore, T),
        )
        for parent, child, T in zip(parents, children, T_parent_children)
    ]
    return types[TF_MESSAGE](transforms=transforms)


def image_message(typestore, seconds: float, frame_id: str, image: np.ndarray):
    """(320, 240, 3) uint8 RGB -> a ``sensor_msgs/msg/Image`` (encoding rgb8) stamped ``seconds``."""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    rows, cols = image.shape[:2]
    return typestore.types[IMAGE](header=_header(typestore, seconds, frame_id), height=rows, width=cols,
                                  encoding="rgb8", is_bigendian=0, step=3 * cols, data=image.reshape(-1))


def write_sequence_bag(
    path: str | os.PathLike,
    stamps: np.ndarray,
    T_world_sensors: np.ndarray,
    images: np.ndarray,
    image_topics: list[str],
    sensor_frames: list[str],
    world_frame: str = "world",
    storage: str = "mcap",
) -> Path:
    """Write F frames of L sensors to a new ROS 2 bag folder ``path`` (storage "mcap" or "sqlite3") -> path.

    stamps (F,) seconds; T_world_sensors (F, L, 4, 4) metres; images (F, L, 320, 240, 3) uint8 RGB. Per frame: a
    ``sensor_msgs/msg/Image`` (rgb8, header.frame_id = the sensor's frame) on each of ``image_topics``, and one /tf
    ``TFMessage`` with the L transforms ``world_frame`` -> sensor frame, all stamped (header and log time) with the
    frame's stamp. ``read_bag_frames(path, image_topics, sensor_frames, world_frame)`` reads it back.
    """
    T = np.asarray(T_world_sensors, dtype=np.float64)
    if T.ndim != 4 or T.shape[2:] != (4, 4):
        raise InputError(f"{path}: T_world_sensors must have shape (F, L, 4, 4), got {T.shape}")
    n_frames, n_sensors = T.shape[:2]
    images = np.asarray(images)
    if images.shape != (n_frames, n_sensors) + TACTILE_IMAGE_SHAPE or images.dtype != np.uint8:
        raise InputError(f"{path}: images must be uint8 of shape {(n_frames, n_sensors) + TACTILE_IMAGE_SHAPE}, got "
                         f"{images.dtype} {images.shape}")
    if len(image_topics) != n_sensors or len(sensor_frames) != n_sensors:
        raise InputError(f"{path}: {len(image_topics)} image topics and {len(sensor_frames)} sensor frames for "
                         f"{n_sensors} sensors (one each)")
    stamps = _check_stamps(stamps, n_frames, path)
    typestore = _typestore()
    with _new_writer(path, storage) as writer:
        image_conns = [writer.add_connection(topic, IMAGE, typestore=typestore) for topic in image_topics]
        tf_conn = writer.add_connection("/tf", TF_MESSAGE, typestore=typestore)
        for f in range(n_frames):
            log_time = _log_time(stamps[f])
            tf = tf_message(typestore, stamps[f], [world_frame] * n_sensors, sensor_frames, T[f])
            writer.write(tf_conn, log_time, typestore.serialize_cdr(tf, TF_MESSAGE))
            for conn, frame_id, image in zip(image_conns, sensor_frames, images[f]):
                msg = image_message(typestore, stamps[f], frame_id, image)
                writer.write(conn, log_time, typestore.serialize_cdr(msg, IMAGE))
    return Path(path)


def write_pose_bag(
    path: str | os.PathLike,
    stamps: np.ndarray,
    T_world_object: np.ndarray,
    frame_id: str = "world",
    topic: str = POSE_TOPIC,
    storage: str = "mcap",
) -> Path:
    """Write object poses to a new ROS 2 bag ``path`` as ``geometry_msgs/msg/PoseStamped`` on ``topic`` -> path.

    stamps (F,) seconds; T_world_object (F, 4, 4) metres, in frame ``frame_id``. Frames whose pose holds a NaN (no
    estimate) are left out. ``path`` is a new bag folder (storage "mcap" or "sqlite3"), or a new lone ``.mcap`` /
    ``.db3`` file (its storage then), which ``read_bag_frames`` and ``read_pose_bag`` read as they read a folder.
    """
    T = np.asarray(T_world_object, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"{path}: T_world_object must have shape (F, 4, 4), got {T.shape}")
    stamps = _check_stamps(stamps, len(T), path)
    path = Path(path)
    lone = {".mcap": "mcap", ".db3": "sqlite3"}.get(path.suffix)
    if lone is None:
        _write_pose_messages(path, stamps, T, frame_id, topic, storage)
        return path
    if path.exists():
        raise InputError(f"{path}: exists already; a bag is written to a new file")
    folder = path.with_name(path.name + ".tmp-bag")
    shutil.rmtree(folder, ignore_errors=True)
    try:
        _write_pose_messages(folder, stamps, T, frame_id, topic, lone)
        (written,) = folder.glob(f"*{path.suffix}")
        os.replace(written, path)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return path


def _write_pose_messages(path: Path, stamps: np.ndarray, T: np.ndarray, frame_id: str, topic: str,
                         storage: str) -> None:
    """``write_pose_bag``'s messages into a new bag folder ``path``."""
    types = (typestore := _typestore()).types
    with _new_writer(path, storage) as writer:
        conn = writer.add_connection(topic, POSE_STAMPED, typestore=typestore)
        for stamp, pose in zip(stamps, T):
            if np.any(np.isnan(pose)):
                continue
            x, y, z, w = rotmat_to_quaternion(pose[:3, :3])
            msg = types[POSE_STAMPED](
                header=_header(typestore, stamp, frame_id),
                pose=types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](x=float(pose[0, 3]), y=float(pose[1, 3]),
                                                              z=float(pose[2, 3])),
                    orientation=types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w)),
                ),
            )
            writer.write(conn, _log_time(stamp), typestore.serialize_cdr(msg, POSE_STAMPED))


def read_pose_bag(path: str | os.PathLike, topic: str = POSE_TOPIC) -> tuple[np.ndarray, np.ndarray]:
    """The ``geometry_msgs/msg/PoseStamped`` messages of ``topic`` in a ROS 2 bag -> (stamps (F,) seconds,
    poses (F, 4, 4) metres), in bag order. InputError listing the bag's topics when ``topic`` is not one of them."""
    typestore = _typestore()
    stamps, poses = [], []
    with _open_reader(path) as reader:
        conns = _topic_connections(reader, path, [topic], (POSE_STAMPED,))[topic]
        for conn, log_time, raw in reader.messages(connections=conns):
            msg = typestore.deserialize_cdr(raw, conn.msgtype)
            p, q = msg.pose.position, msg.pose.orientation
            stamps.append(_header_seconds(msg.header, log_time))
            poses.append(make_pose(quaternion_to_rotmat(np.array([q.x, q.y, q.z, q.w])), np.array([p.x, p.y, p.z])))
    return np.array(stamps, dtype=np.float64), np.stack(poses) if poses else np.zeros((0, 4, 4))
