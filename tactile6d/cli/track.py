"""``tactile6d track``: follow an object's pose over a stream of frames (``tactile6d.estimation.tracker``).

Input, one of:

- ``--sequence DIR``: frames as numbered scene folders ``DIR/000000``, ``DIR/000001``, ... (each in the
  paper's triplet layout: ``poses_sensors.txt`` and ``Image_heatmap_<i>.png``), the sensors' no-contact
  images as ``DIR/background_<i>.png`` (or per frame folder), timestamps in ``DIR/frames.json``
  (``tactile6d.data.sequence_dirs``);
- ``--bag FILE --images TOPIC [TOPIC ...]``: a ROS 2 bag (a rosbag2 folder, or one .mcap / .db3 file), one
  ``sensor_msgs/Image`` (rgb8, bgr8) or ``CompressedImage`` topic per sensor; the sensor poses from the
  bag's TF tree (``--frames FRAME [FRAME ...]``: each sensor's TF frame, in the order of ``--images``,
  looked up from ``--world-frame``) or fixed (``--poses FILE``: one ``x y z ax ay az angle`` line per
  sensor). Frames follow the first image topic; the others are matched within ``--sync-tolerance``
  seconds (``tactile6d.data.rosbag_io``).

``--background`` gives the sensors' no-contact images (one file for all or one per sensor), or with
``first-frames`` takes each sensor's from the stream itself: its mean over the first ``--background-frames``
frames, which must show nothing touching (``tactile6d.perception.stream_background``; a recording started
before the fingers close). Without either, the tracker reads a known unit's images against its no-contact image
(``encode.KNOWN_UNITS``, and your own units' given with ``--known-units``; a ``warning:`` line names the unit).
When a no-contact image looked like another unit's and no known unit's agreed, a ``hint:`` line names
``first-frames``.

``--sensor-offsets FILE`` corrects every frame's sensor poses by each sensor's mounting offset (``tactile6d
calibrate-sensors``) before the tracker sees them.

Output: one line per frame on stdout: ``<frame> <stamp> <mode> x y z ax ay az angle <confidence>`` (mode
``redetect``, ``update`` or ``hold``; stamp the input's seconds, else frame number / ``--fps``; confidence ``-``
when unknown), or with ``--json`` one
JSON object per frame (pose as a 4x4 matrix, mode, the re-detection's reason, confidence, whether it is
ambiguous and the rival poses that make it so, which sensors touch, the fit terms, seconds). ``--bop FILE``
also writes a BOP result CSV (``scene_id`` from ``--scene-id``, ``im_id`` the frame, ``obj_id`` the object's
YCB-Video id or ``--obj-id``, score the confidence, t in mm, time the frame's seconds); ``--out-bag PATH`` writes
the poses as ``geometry_msgs/PoseStamped`` (``--out-topic``). Frames without a pose yet are left out of both. ``--plot PNG``
draws the track over time (``tactile6d.evaluation.stream_figure``): the position and turn from the first pose, the
re-detections, held and ambiguous frames, the sensors touching and the confidence.

A summary goes to stderr at the end (frames, re-detections, held and ambiguous frames, median seconds per
updated frame).

The frames go to ``Tracker.track``: ``track.read_ahead`` worker processes read the next frame's contact
patches while this process follows the current one (the same poses as frame-by-frame updates), so a frame's
line is written when the next frame has been read from the input.
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import sys
import warnings
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tactile6d.cli import description
from tactile6d.cli.estimate import (EstimatorCache, add_known_units_argument, add_sensor_offsets_argument,
                                    known_units_option, read_sensor_offsets, split_overrides, use_solver_devices,
                                    write)
from tactile6d.cli.objects import KnownObjects
from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError, Tactile6dError
from tactile6d.core.geometry import pose_to_line, text_to_poses
from tactile6d.data import bop, rosbag_io, sequence_dirs
from tactile6d.data.hdf5 import read_background_images
from tactile6d.perception import photometric, stream_background
from tactile6d.perception.inputs import UnderdeterminedPoseWarning

if TYPE_CHECKING:
    from tactile6d.estimation.tracker import TrackedFrame

FIRST_FRAMES = "first-frames"  # --background's word for "each sensor's mean over the stream's first frames"


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="tactile6d track", description=description(__doc__),
        usage=("tactile6d track --object NAME --sequence DIR [options] [key=value ...]\n"
               "       tactile6d track --object NAME --bag FILE --images TOPIC [TOPIC ...] "
               "(--frames FRAME [FRAME ...] | --poses FILE) [options] [key=value ...]"))
    parser.add_argument("--object", required=True, help="the object held (see `tactile6d estimate`'s objects)")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--sequence", metavar="DIR", help="numbered scene folders, one per frame")
    source.add_argument("--bag", metavar="FILE", help="a ROS 2 bag (folder, .mcap or .db3)")
    parser.add_argument("--images", nargs="+", metavar="TOPIC", help="with --bag: one image topic per sensor")
    poses = parser.add_mutually_exclusive_group()
    poses.add_argument("--frames", nargs="+", metavar="FRAME", help="with --bag: each sensor's TF frame")
    poses.add_argument("--poses", metavar="FILE", help="with --bag: fixed sensor poses (poses_sensors.txt format)")
    parser.add_argument("--world-frame", default="world", help="with --frames: the TF frame poses are given in")
    parser.add_argument("--sync-tolerance", type=float, default=0.02,
                        help="with --bag: seconds within which the other sensors' images join a frame")
    parser.add_argument("--tf-tolerance", type=float, default=0.25,
                        help="with --frames: a frame whose TF chain for some sensor uses a transform farther than "
                             "this (seconds) from its stamp is skipped (TF stopped; default 0.25)")
    parser.add_argument("--raw-camera-frames", action="store_true",
                        help="with --bag: the images are the camera's raw frames, 320 wide x 240 high; each is turned "
                             "as digit-interface's Digit.get_frame() turns it (np.rot90)")
    parser.add_argument("--fps", type=float, default=30.0,
                        help="frame rate assumed for stamps when the input has none (a sequence without frames.json): "
                             "frame number / fps")
    add_sensor_offsets_argument(parser, "every frame's sensor poses")
    parser.add_argument("--background", nargs="+", default=None, metavar="PNG",
                        help="the sensors' no-contact image(s): one for every sensor or one per sensor, or "
                             f"'{FIRST_FRAMES}' (each sensor's mean over the stream's first --background-frames "
                             "frames, which must show nothing touching) (default: the sequence folder's "
                             "background_<i>.png, else render.background)")
    parser.add_argument("--background-frames", type=int, default=stream_background.DEFAULT_FRAMES, metavar="N",
                        help=f"with --background {FIRST_FRAMES}: how many of the first frames "
                             f"(default {stream_background.DEFAULT_FRAMES}, at least {stream_background.MIN_FRAMES})")
    add_known_units_argument(parser)
    parser.add_argument("--artifacts", default=None, help="artifacts directory (default: paths.artifacts_dir)")
    parser.add_argument("--json", action="store_true", help="one JSON object per frame (JSON Lines)")
    parser.add_argument("--bop", metavar="FILE", help="also write a BOP result CSV")
    parser.add_argument("--scene-id", type=int, default=0, help="BOP scene_id of the stream (default 0)")
    parser.add_argument("--obj-id", type=int, default=None, help="BOP obj_id (default: the YCB-Video id of --object)")
    parser.add_argument("--out-bag", metavar="PATH", help="also write the poses as geometry_msgs/PoseStamped: a new "
                        "bag folder, or one file when PATH ends in .mcap or .db3")
    parser.add_argument("--out-topic", default=rosbag_io.POSE_TOPIC, help="topic of --out-bag's poses")
    parser.add_argument("--plot", metavar="PNG", help="also draw the track over time: position and turn from the "
                        "first pose, re-detections, held and ambiguous frames, sensors touching, confidence")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (e.g. track.redetect_every=30)")
    args = parser.parse_args(argv)
    for name in ("images", "frames"):  # greedy lists may have swallowed overrides
        words, args.overrides = split_overrides(getattr(args, name), list(args.overrides))
        setattr(args, name, words)
    args.background, args.overrides = split_overrides(args.background, list(args.overrides))
    args.known_units, args.overrides = split_overrides(args.known_units, list(args.overrides))
    if args.background_frames < stream_background.MIN_FRAMES:
        parser.error(f"--background-frames must be at least {stream_background.MIN_FRAMES}")
    if FIRST_FRAMES in (args.background or []) and args.background != [FIRST_FRAMES]:
        parser.error(f"--background {FIRST_FRAMES} stands alone (not beside files)")
    if args.bag is not None:
        if not args.images:
            parser.error("--bag needs --images TOPIC [TOPIC ...]")
        if (args.frames is None) == (args.poses is None):
            parser.error("--bag needs the sensor poses: --frames FRAME [FRAME ...] (TF) or --poses FILE (fixed)")
    elif args.images or args.frames or args.poses or args.raw_camera_frames:
        parser.error("--images, --frames, --poses and --raw-camera-frames go with --bag")
    if not args.fps > 0:
        parser.error(f"--fps must be a positive number of frames per second, got {args.fps}")
    if args.out_bag is not None and Path(args.out_bag).exists():  # found now, not after the whole stream is tracked
        parser.error(f"--out-bag {args.out_bag} exists already; the poses are written to a new bag")
    if args.bop is not None:
        args.obj_id = bop.object_name_to_bop_id(args.object, args.obj_id)  # an unknown object fails here, not at the end
    return args


Frame = tuple[int, float | None, np.ndarray, np.ndarray, np.ndarray | None]  # index, stamp, T, images, backgrounds


def frames_of(args: argparse.Namespace) -> Iterator[Frame]:
    """The input's frames in order, from a sequence folder or a bag; the folder listing, the bag, its topics and TF
    chains are checked now (InputError), each frame as it is read. A frame without a stamp gets number / ``--fps``."""
    if args.sequence is not None:
        frames = sequence_dirs.iter_sequence_dir(args.sequence)
    else:
        frames = bag_frames(args)
    return ((index, index / args.fps if stamp is None else stamp, T, images, backgrounds)
            for index, stamp, T, images, backgrounds in frames)


def bag_frames(args: argparse.Namespace) -> Iterator[Frame]:
    """``--bag``'s frames (``rosbag_io.read_bag_frames``, which checks the bag at the call), numbered from 0."""
    fixed = None
    if args.poses is not None:
        path = Path(args.poses)
        if not path.is_file():
            raise InputError(f"--poses {path} not found")
        try:
            fixed = text_to_poses(path.read_text())
        except ValueError as exc:
            raise InputError(f"--poses {path}: {exc}") from exc
    frames = rosbag_io.read_bag_frames(args.bag, args.images, args.frames, args.world_frame, fixed,
                                       args.sync_tolerance, args.tf_tolerance, args.raw_camera_frames)
    return ((k, frame.stamp, frame.T_world_sensors, frame.images, None) for k, frame in enumerate(frames))


def backgrounds_from_first_frames(frames: Iterator[Frame], count: int, model) -> tuple[np.ndarray, Iterator[Frame]]:
    """``--background first-frames``: each sensor's no-contact image from the stream's first ``count`` frames
    (``stream_background.stream_start_to_backgrounds``, their contacts read with the patch ``model``) and the
    stream whole again (those frames first). InputError when the stream is shorter or they show a contact."""
    first = list(itertools.islice(frames, count))
    if len(first) < count:
        raise InputError(f"--background {FIRST_FRAMES}: the input holds {len(first)} frames, fewer than "
                         f"--background-frames {count}")
    backgrounds = stream_background.stream_start_to_backgrounds(np.stack([frame[3] for frame in first]), model)
    return backgrounds, itertools.chain(first, frames)


def frame_line(index: int, stamp: float | None, answer: TrackedFrame) -> str:
    stamp_text = "-" if stamp is None else f"{stamp:.6f}"
    confidence = "-" if answer.confidence is None else f"{answer.confidence:.3f}"
    pose = "nan" if not np.isfinite(answer.pose).all() else pose_to_line(answer.pose)
    return f"{index} {stamp_text} {answer.mode} {pose} {confidence}"


def warning_lines(caught: list[warnings.WarningMessage]) -> list[str]:
    """One ``warning:`` line per kind of warning the stream drew: the light's warnings come again at every
    re-detection with other figures, so messages that differ only in their figures (not in the image or
    sensor they name) are told once, with how many times they came."""
    first: dict[tuple, str] = {}
    counts: dict[tuple, int] = {}
    for w in caught:
        text = " ".join(str(w.message).split())
        key = (w.category, re.sub(r"(?<!image )(?<!sensor )\d+(\.\d+)?", "#", text))
        first.setdefault(key, text)
        counts[key] = counts.get(key, 0) + 1
    return [f"warning: {text}" + (f" ({counts[key]} times, the figures of the first)" if counts[key] > 1 else "")
            for key, text in first.items()]


def hint_lines(caught: list[warnings.WarningMessage], learned: bool) -> list[str]:
    """A ``hint:`` line after the warnings when a no-contact image looked like another unit's and was read against
    it all the same (``photometric.UnitWarning``; not a ``KnownUnitWarning``, whose image was read against the known
    unit's it agrees with) and the stream's own first frames were not taken (``learned``)."""
    misread = [w for w in caught if issubclass(w.category, photometric.UnitWarning)
               and not issubclass(w.category, photometric.KnownUnitWarning)]
    if learned or not misread:
        return []
    return [f"hint: a stream recorded from before the fingers touch gives each unit's own no-contact image: "
            f"--background {FIRST_FRAMES}"]


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    cfg = compose_config(args.overrides)
    use_solver_devices(cfg)
    from tactile6d.estimation.tracker import Tracker, TrackSettings  # torch, JAX: not loaded for --help
    artifacts = args.artifacts if args.artifacts is not None else cfg.paths.artifacts_dir
    learned = args.background == [FIRST_FRAMES]
    background = read_background_images(args.background) if args.background and not learned else None
    cache = EstimatorCache(KnownObjects(artifacts, cfg), cfg, background, read_sensor_offsets(args),
                           known_units_option(args.known_units, args.background))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", photometric.LightWarning)
        warnings.simplefilter("once", UnderdeterminedPoseWarning)
        frames = frames_of(args)  # the input checked before the artifacts are loaded
        estimator = cache.load(args.object)
        if learned:
            background, frames = backgrounds_from_first_frames(frames, args.background_frames, estimator.patch_model)
            write(f"note: each sensor's no-contact image is its mean over the first {args.background_frames} frames "
                  f"(--background {FIRST_FRAMES}), which show nothing touching", sys.stderr)
        track = follow(frames, Tracker(estimator, TrackSettings.from_cfg(cfg.track)), cache, background, learned, args)
    for line in warning_lines(caught) + hint_lines(caught, learned):
        write(line, sys.stderr)
    if not track.modes and track.error is None:
        raise InputError("the input holds no frame")
    write_outputs(track, args)
    updates = [s for s, m in zip(track.seconds, track.modes) if m == "update"]
    median = f"{1e3 * np.median(updates):.1f} ms" if updates else "-"
    write(f"{len(track.modes)} frames: {track.modes.count('redetect')} re-detections, {track.modes.count('hold')} "
          f"held, {sum(track.drawn['ambiguous'])} ambiguous; median update {median}", sys.stderr)
    if track.error is not None:
        # The frames before the one that failed were answered and their outputs written: say so, then fail.
        written = [name for name, path in (("--bop", args.bop), ("--out-bag", args.out_bag), ("--plot", args.plot))
                   if path is not None]
        if track.modes and written:
            write(f"note: stopped at the error below; {', '.join(written)} hold the {len(track.modes)} frames "
                  "tracked before it", sys.stderr)
        raise track.error
    return 0


@dataclass
class Followed:
    """What ``follow`` gathered over a stream: per frame answered, its stamp, pose, BOP row (frames with a pose),
    seconds and mode, what ``--plot`` draws; and the error that ended the stream early, if one did."""

    stamps: list = field(default_factory=list)
    poses: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    seconds: list = field(default_factory=list)
    modes: list = field(default_factory=list)
    drawn: dict = field(default_factory=lambda: {"times": [], "poses": [], "confidence": [], "ambiguous": [],
                                                 "touching": []})
    error: Tactile6dError | None = None


def follow(frames: Iterator[Frame], tracker, cache: EstimatorCache, background, learned: bool,
           args: argparse.Namespace) -> Followed:
    """Each frame through ``tracker.track``, its line written as it is answered. A frame that cannot be read, or
    that the tracker refuses (a Tactile6dError), ends the stream: the frames before it are answered all the same,
    and the error is kept in ``Followed.error`` for the caller to raise once the outputs are written."""
    out = Followed()
    read = deque()  # (index, stamp) of the frames handed to the tracker and not yet answered

    def stream():
        try:
            for index, stamp, T, images, frame_backgrounds in frames:
                read.append((index, stamp))
                if learned:  # per frame, as a sequence folder's own: the estimator's default is render.background
                    yield cache.sensor_poses(T), images, background
                else:
                    yield cache.sensor_poses(T), images, None if background is not None else frame_backgrounds
        except Tactile6dError as exc:  # reading the next frame failed: the tracker answers those read before it
            out.error = exc

    with tracker:
        try:
            for answer in tracker.track(stream()):
                index, stamp = read.popleft()
                add_answer(out, index, stamp, answer, args)
        except Tactile6dError as exc:
            out.error = exc
    return out


def add_answer(out: Followed, index: int, stamp: float, answer: TrackedFrame, args: argparse.Namespace) -> None:
    """One answered frame: its line on stdout, and what the outputs and the summary need of it in ``out``."""
    if args.json:
        write(json.dumps({"frame": index, "stamp": stamp, **answer.to_dict()}), sys.stdout)
    else:
        write(frame_line(index, stamp, answer), sys.stdout)
    out.seconds.append(answer.seconds)
    out.modes.append(answer.mode)
    out.drawn["times"].append(stamp)
    out.drawn["poses"].append(answer.pose)
    out.drawn["confidence"].append(np.nan if answer.confidence is None else answer.confidence)
    out.drawn["ambiguous"].append(answer.ambiguous)
    out.drawn["touching"].append(int(np.count_nonzero(answer.touching)))
    if np.isfinite(answer.pose).all():
        out.stamps.append(stamp)
        out.poses.append(answer.pose)
        score = 1.0 if answer.confidence is None else answer.confidence
        out.rows.append(bop.BopRow(args.scene_id, index, args.obj_id or 0, score, answer.pose, answer.seconds))


def write_outputs(track: Followed, args: argparse.Namespace) -> None:
    """``--bop``, ``--out-bag`` and ``--plot`` of the frames answered (none when no frame was)."""
    if not track.modes:
        return
    if args.bop is not None:
        bop.write_bop_csv(args.bop, track.rows)
    if args.out_bag is not None:
        rosbag_io.write_pose_bag(args.out_bag, np.array(track.stamps), np.array(track.poses).reshape(-1, 4, 4),
                                 args.world_frame, args.out_topic)
    if args.plot is not None:
        import matplotlib.pyplot as plt  # matplotlib: only when drawing

        from tactile6d.evaluation.stream_figure import stream_figure

        drawn = track.drawn
        figure = stream_figure(np.array(drawn["times"]), np.array(drawn["poses"]), track.modes,
                               np.array(drawn["confidence"]), np.array(drawn["ambiguous"]), np.array(drawn["touching"]),
                               args.object)
        figure.savefig(args.plot, dpi=100)
        plt.close(figure)
