import warnings

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import invert_pose, make_pose, quaternion_to_rotmat, random_rotations, rotvec_to_rotmat
from tactile6d.data.rosbag_io import (
    COMPRESSED_IMAGE,
    IMAGE,
    TF_MESSAGE,
    SkippedFramesWarning,
    image_message,
    read_bag_frames,
    read_pose_bag,
    rotmat_to_quaternion,
    tf_message,
    write_pose_bag,
    write_sequence_bag,
)

TOPICS = ["/digit0/image", "/digit1/image", "/digit2/image"]
FRAMES = ["digit_0", "digit_1", "digit_2"]
TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
N_FRAMES = 4


def random_poses(shape, rng):
    n = int(np.prod(shape))
    return make_pose(random_rotations(n, rng).reshape(shape + (3, 3)), rng.uniform(-0.3, 0.3, size=shape + (3,)))


@pytest.fixture
def recording():
    """4 frames of 3 sensors at 30 Hz: stamps (4,), T_world_sensors (4, 3, 4, 4), distinct images
    (4, 3, 320, 240, 3)."""
    rng = np.random.default_rng(7)
    stamps = 1_700_000_000.25 + np.arange(N_FRAMES) / 30.0
    images = rng.integers(0, 256, size=(N_FRAMES, 3, 320, 240, 3), dtype=np.uint8)
    return stamps, random_poses((N_FRAMES, 3), rng), images


def write_bag(path, messages, storage=StoragePlugin.MCAP):
    """messages: (topic, msgtype, seconds, message) in any order -> a bag written in log-time order."""
    with Writer(path, version=9, storage_plugin=storage) as writer:
        conns = {}
        for topic, msgtype, seconds, msg in sorted(messages, key=lambda m: m[2]):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=TYPESTORE)
            writer.write(conns[topic], int(round(seconds * 1e9)), TYPESTORE.serialize_cdr(msg, msgtype))
    return path


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_sequence_round_trip(tmp_path, recording, storage):
    stamps, T, images = recording
    bag = write_sequence_bag(tmp_path / "bag", stamps, T, images, TOPICS, FRAMES, storage=storage)
    suffix = {"mcap": ".mcap", "sqlite3": ".db3"}[storage]
    (storage_file,) = bag.glob("*" + suffix)
    for source in (bag, storage_file):  # the bag folder, or its storage file alone
        frames = list(read_bag_frames(source, TOPICS, FRAMES))
        assert len(frames) == N_FRAMES
        for f, frame in enumerate(frames):
            assert abs(frame.stamp - stamps[f]) < 1e-6  # float seconds of an epoch time: ~2e-7 s resolution
            assert frame.images.dtype == np.uint8 and frame.images.shape == (3, 320, 240, 3)
            np.testing.assert_array_equal(frame.images, images[f])
            np.testing.assert_allclose(frame.T_world_sensors, T[f], atol=1e-9)


def test_tf_tree_with_an_intermediate_frame_and_static_transforms(tmp_path, recording):
    """world -> hand moves (/tf), hand -> digit_i is fixed (/tf_static). Each frame takes, per edge, the latest
    transform stamped at or before it, the first frame (before any world -> hand) the earliest one."""
    stamps, _, images = recording
    rng = np.random.default_rng(3)
    T_hand_digits = random_poses((3,), rng)
    T_world_hands = random_poses((N_FRAMES,), rng)
    hand_stamps = stamps + 0.01  # each 10 ms after its frame: frame k sees hand pose k - 1, frame 0 hand pose 0
    messages = [("/tf_static", TF_MESSAGE, stamps[0] - 1.0, tf_message(TYPESTORE, 0.0, ["hand"] * 3, FRAMES,
                                                                         T_hand_digits))]
    messages += [("/tf", TF_MESSAGE, s, tf_message(TYPESTORE, s, ["/world"], ["hand"], [T]))  # ROS 1 style "/world"
                 for s, T in zip(hand_stamps, T_world_hands)]
    messages += [(topic, IMAGE, s, image_message(TYPESTORE, s, frame, images[f, i]))
                 for f, s in enumerate(stamps) for i, (topic, frame) in enumerate(zip(TOPICS, FRAMES))]
    bag = write_bag(tmp_path / "bag", messages)

    frames = list(read_bag_frames(bag, TOPICS, FRAMES, world_frame="world"))
    assert len(frames) == N_FRAMES
    for f, frame in enumerate(frames):
        expected = T_world_hands[max(f - 1, 0)] @ T_hand_digits
        np.testing.assert_allclose(frame.T_world_sensors, expected, atol=1e-9)
        np.testing.assert_array_equal(frame.images, images[f])
    # any frame of the tree as the reference: a sensor's parent, or another sensor (up to their common ancestor)
    (first, *_) = read_bag_frames(bag, TOPICS, FRAMES, world_frame="hand")
    np.testing.assert_allclose(first.T_world_sensors, T_hand_digits, atol=1e-9)
    (first, *_) = read_bag_frames(bag, TOPICS, FRAMES, world_frame="digit_0")
    np.testing.assert_allclose(first.T_world_sensors, invert_pose(T_hand_digits[0]) @ T_hand_digits, atol=1e-9)

    with pytest.raises(InputError, match=r"sensor frame 'digit_9' is in no /tf or /tf_static transform; the bag's "
                                         r"frames: digit_0, digit_1, digit_2, hand, world"):
        read_bag_frames(bag, TOPICS, ["digit_0", "digit_1", "digit_9"])
    with pytest.raises(InputError, match=r"world frame 'map' is in no /tf"):
        read_bag_frames(bag, TOPICS, FRAMES, world_frame="map")


def test_disconnected_tf_trees_are_named(tmp_path, recording):
    stamps, T, images = recording
    messages = [("/tf", TF_MESSAGE, stamps[0], tf_message(TYPESTORE, stamps[0], ["world", "world", "odom"], FRAMES,
                                                          T[0]))]
    messages += [(topic, IMAGE, stamps[0], image_message(TYPESTORE, stamps[0], frame, images[0, i]))
                 for i, (topic, frame) in enumerate(zip(TOPICS, FRAMES))]
    bag = write_bag(tmp_path / "bag", messages, storage=StoragePlugin.SQLITE3)
    with pytest.raises(InputError, match=r"no chain of TF transforms connects world frame 'world' \(tree root "
                                         r"'world'\) to sensor frame 'digit_2' \(tree root 'odom'\)"):
        read_bag_frames(bag, TOPICS, FRAMES)


def test_bgr8_and_compressed_images_with_fixed_poses(tmp_path, recording):
    stamps, T, images = recording
    messages = []
    for f, s in enumerate(stamps):
        bgr = image_message(TYPESTORE, s, "digit_0", images[f, 0][..., ::-1])
        bgr.encoding = "bgr8"
        ok, png = cv2.imencode(".png", np.ascontiguousarray(images[f, 1][..., ::-1]))
        compressed = TYPESTORE.types[COMPRESSED_IMAGE](header=bgr.header, format="png", data=png.reshape(-1))
        padded = TYPESTORE.types[IMAGE](header=bgr.header, height=320, width=240, encoding="rgb8", is_bigendian=0,
                                        step=240 * 3 + 8, data=np.pad(images[f, 2], ((0, 0), (0, 8 // 3 + 1), (0, 0)))
                                        .reshape(320, -1)[:, : 240 * 3 + 8].reshape(-1))
        messages += [("/bgr", IMAGE, s, bgr), ("/png", COMPRESSED_IMAGE, s, compressed), ("/rgb", IMAGE, s, padded)]
    bag = write_bag(tmp_path / "bag", messages)
    fixed = T[0]
    frames = list(read_bag_frames(bag, ["/bgr", "/png", "/rgb"], fixed_poses=fixed))
    assert len(frames) == N_FRAMES
    for f, frame in enumerate(frames):
        np.testing.assert_array_equal(frame.images, images[f])  # RGB again
        np.testing.assert_array_equal(frame.T_world_sensors, fixed)
    # this bag has no TF to place sensors by frame
    with pytest.raises(InputError, match=r"no TF transforms .* give fixed_poses instead"):
        read_bag_frames(bag, ["/bgr", "/png", "/rgb"], FRAMES)


def test_a_rotated_camera_and_other_encodings_are_named(tmp_path, recording):
    stamps, _, images = recording
    rotated = image_message(TYPESTORE, stamps[0], "digit_0", np.ascontiguousarray(np.rot90(images[0, 0])))
    mono = TYPESTORE.types[IMAGE](header=rotated.header, height=320, width=240, encoding="mono8", is_bigendian=0,
                                  step=240, data=images[0, 0, :, :, 0].reshape(-1))
    bag = write_bag(tmp_path / "bag", [("/rotated", IMAGE, stamps[0], rotated), ("/mono", IMAGE, stamps[0], mono)])
    with pytest.raises(InputError, match=r"/rotated: an image is 320 wide x 240 high.*rotated by 90 degrees.*np.rot90"
                                         r".*--raw-camera-frames turns them so"):
        list(read_bag_frames(bag, ["/rotated"], fixed_poses=np.eye(4)[None]))
    # a raw camera frame is np.rot90(image) turned back: raw = rot90(image, -1), so rot90(raw) is the image
    raw = image_message(TYPESTORE, stamps[0], "digit_0", np.ascontiguousarray(np.rot90(images[0, 0], -1)))
    raw_bag = write_bag(tmp_path / "raw", [("/raw", IMAGE, stamps[0], raw)])
    (frame,) = read_bag_frames(raw_bag, ["/raw"], fixed_poses=np.eye(4)[None], raw_camera_frames=True)
    np.testing.assert_array_equal(frame.images[0], images[0, 0])
    with pytest.raises(InputError, match=r"/upright: an image is 240 wide x 320 high; a DIGIT camera's raw frame "
                                         r"\(--raw-camera-frames\) is 320 wide x 240 high"):
        upright = write_bag(tmp_path / "upright", [("/upright", IMAGE, stamps[0], image_message(
            TYPESTORE, stamps[0], "digit_0", images[0, 0]))])
        list(read_bag_frames(upright, ["/upright"], fixed_poses=np.eye(4)[None], raw_camera_frames=True))
    with pytest.raises(InputError, match=r"/mono: image encoding 'mono8', expected rgb8 or bgr8"):
        list(read_bag_frames(bag, ["/mono"], fixed_poses=np.eye(4)[None]))


def test_frames_are_driven_by_the_first_topic_and_matched_within_the_tolerance(tmp_path, recording):
    stamps, T, images = recording
    decoy = np.zeros((320, 240, 3), np.uint8)
    messages = []
    for f, s in enumerate(stamps):
        messages.append((TOPICS[0], IMAGE, s, image_message(TYPESTORE, s, FRAMES[0], images[f, 0])))
        messages.append((TOPICS[1], IMAGE, s + 0.015, image_message(TYPESTORE, s + 0.015, FRAMES[1], images[f, 1])))
        if f != 2:  # sensor 2 drops frame 2; its nearest message is 4 ms late, a decoy 12 ms early
            messages.append((TOPICS[2], IMAGE, s + 0.004, image_message(TYPESTORE, s + 0.004, FRAMES[2], images[f, 2])))
            messages.append((TOPICS[2], IMAGE, s - 0.012, image_message(TYPESTORE, s - 0.012, FRAMES[2], decoy)))
    bag = write_bag(tmp_path / "bag", messages)
    with pytest.warns(SkippedFramesWarning, match=r"1 of 4 frames skipped: sensor 2 \(/digit2/image\) had no image "
                                                  r"within 0.02 s of the first topic's in 1, from 1700000000.317 s on"):
        frames = list(read_bag_frames(bag, TOPICS, fixed_poses=T[0]))
    assert len(frames) == 3
    for frame, f in zip(frames, [0, 1, 3]):
        assert abs(frame.stamp - stamps[f]) < 1e-6
        np.testing.assert_array_equal(frame.images, images[f])
    # a tighter tolerance drops sensor 1 (15 ms late) from every frame
    with pytest.warns(SkippedFramesWarning, match=r"4 of 4 frames skipped"):
        assert list(read_bag_frames(bag, TOPICS, fixed_poses=T[0], sync_tolerance=0.01)) == []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(list(read_bag_frames(bag, TOPICS[:2], fixed_poses=T[0, :2]))) == 4


def test_bad_arguments_and_missing_topics(tmp_path, recording):
    stamps, T, images = recording
    bag = write_sequence_bag(tmp_path / "bag", stamps, T, images, TOPICS, FRAMES)
    with pytest.raises(InputError, match=r"topic\(s\) /digit3/image not in the bag; its topics: /digit0/image "
                                         r"\(sensor_msgs/msg/Image\), .*/tf \(tf2_msgs/msg/TFMessage\)"):
        read_bag_frames(bag, TOPICS[:2] + ["/digit3/image"], FRAMES)
    with pytest.raises(InputError, match=r"topic /tf carries tf2_msgs/msg/TFMessage, expected sensor_msgs/msg/Image"):
        read_bag_frames(bag, ["/tf"], fixed_poses=T[0, :1])
    with pytest.raises(InputError, match=r"give the sensor poses one way: TF frames, .* \(--frames\), or fixed poses"):
        read_bag_frames(bag, TOPICS)
    with pytest.raises(InputError, match=r"give the sensor poses one way"):
        read_bag_frames(bag, TOPICS, FRAMES, fixed_poses=T[0])
    with pytest.raises(InputError, match=r"an image topic is given twice"):
        read_bag_frames(bag, TOPICS[:2] + TOPICS[:1], FRAMES)
    with pytest.raises(InputError, match=r"^2 sensor TF frames \(--frames\) for 3 image topics"):
        read_bag_frames(bag, TOPICS, FRAMES[:2])
    with pytest.raises(InputError, match=r"^2 fixed sensor poses \(--poses\) for 3 image topics"):
        read_bag_frames(bag, TOPICS, fixed_poses=T[0, :2])
    with pytest.raises(InputError, match=r"ROS 2 bag .*nope not found"):
        read_bag_frames(tmp_path / "nope", TOPICS, FRAMES)
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(InputError, match=r"x\.txt: not a ROS 2 bag"):
        read_bag_frames(tmp_path / "x.txt", TOPICS, FRAMES)
    with pytest.raises(InputError, match=r"bag: exists already"):
        write_sequence_bag(bag, stamps, T, images, TOPICS, FRAMES)
    with pytest.raises(InputError, match=r"bag storage 'rosbag1'"):
        write_sequence_bag(tmp_path / "other", stamps, T, images, TOPICS, FRAMES, storage="rosbag1")


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_pose_bag_round_trip_skips_nan_frames(tmp_path, storage):
    rng = np.random.default_rng(11)
    stamps = 50.0 + np.arange(5) * 0.1
    poses = random_poses((5,), rng)
    poses[2] = np.nan  # no estimate for frame 2
    bag = write_pose_bag(tmp_path / "poses", stamps, poses, storage=storage)
    got_stamps, got_poses = read_pose_bag(bag, "/tactile6d/object_pose")
    keep = [0, 1, 3, 4]
    np.testing.assert_allclose(got_stamps, stamps[keep], atol=1e-9)
    np.testing.assert_allclose(got_poses, poses[keep], atol=1e-9)
    with pytest.raises(InputError, match=r"topic\(s\) /pose not in the bag; its topics: /tactile6d/object_pose"):
        read_pose_bag(bag, "/pose")


def test_rotmat_to_quaternion_is_ros_order_and_inverts_quaternion_to_rotmat():
    q = rotmat_to_quaternion(rotvec_to_rotmat(np.array([0.0, 0.0, np.pi / 2])))
    np.testing.assert_allclose(q, [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-15)
    # half turns (w = 0) about each axis and a diagonal, and random rotations
    R = np.concatenate([rotvec_to_rotmat(np.pi * np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, 0.8, 0]])),
                        random_rotations(1000, np.random.default_rng(0))])
    q = rotmat_to_quaternion(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(quaternion_to_rotmat(q), R, atol=1e-14)


def test_a_sensor_that_falls_silent_holds_up_one_horizon_of_frames_and_is_named(tmp_path, recording, monkeypatch):
    """Sensor 2 publishes for the first 3 of 60 frames: each later frame is decided once the first topic is
    SYNC_HORIZON past it, not at the end of the bag, and the warning names the sensor and when it went."""
    from tactile6d.data import rosbag_io

    stamps = 100.0 + np.arange(60) / 30.0
    image = recording[2][0, 0]
    messages = []
    for f, s in enumerate(stamps):
        for k, topic in enumerate(TOPICS):
            if k < 2 or f < 3:
                messages.append((topic, IMAGE, s, image_message(TYPESTORE, s, FRAMES[k], image)))
    bag = write_bag(tmp_path / "bag", messages)
    held = []
    synchronise = rosbag_io._synchronise

    def watched(messages, *args):
        read = []

        def counting():
            for item in messages:
                read.append(item[1])
                yield item
        for stamp, chosen in synchronise(counting(), *args):
            held.append(read[-1] - stamp if read else 0.0)  # how far the reading ran ahead of the frame decided
            yield stamp, chosen

    monkeypatch.setattr(rosbag_io, "_synchronise", watched)
    with pytest.warns(SkippedFramesWarning, match=r"57 of 60 frames skipped: sensor 2 \(/digit2/image\) had no image "
                                                  r"within 0.02 s of the first topic's in 57, from 100.100 s on"):
        frames = list(read_bag_frames(bag, TOPICS, fixed_poses=np.stack([np.eye(4)] * 3)))
    assert len(frames) == 3
    assert max(held[:-40]) <= rosbag_io.SYNC_HORIZON + 2 / 30.0  # bounded while the bag goes on


def write_in_order(path, stamps, images, order, topics, spacing):
    """Frame f's images (stamped stamps[f]) on every topic, recorded in ``order`` at ``spacing`` seconds apart."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {t: writer.add_connection(t, IMAGE, typestore=TYPESTORE) for t in topics}
        for rank, f in enumerate(order):
            log = int(round((stamps[0] + rank * spacing) * 1e9))
            for k, topic in enumerate(topics):
                msg = image_message(TYPESTORE, stamps[f], FRAMES[k], images[f, k])
                writer.write(conns[topic], log, TYPESTORE.serialize_cdr(msg, IMAGE))
    return path


def test_first_topic_images_out_of_order_are_put_in_order_or_left_out(tmp_path, recording):
    """Frame 2's images recorded after frame 3's, within REORDER_WINDOW, come in stamp order; a frame recorded after
    the window has passed it is left out and counted."""
    from tactile6d.data.rosbag_io import REORDER_WINDOW

    stamps, T, images = recording
    bag = write_in_order(tmp_path / "swapped", stamps, images, [0, 1, 3, 2], TOPICS, 1 / 30.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frames = list(read_bag_frames(bag, TOPICS, fixed_poses=T[0]))
    np.testing.assert_allclose([f.stamp for f in frames], stamps, atol=1e-6)
    for frame, f in zip(frames, range(4)):
        np.testing.assert_array_equal(frame.images, images[f])
    # at 10 Hz, frame 0 recorded after frame 3: frames 1 and 2 were decided by then, so frame 0 is late
    slow = 50.0 + np.arange(4) * REORDER_WINDOW
    bag = write_in_order(tmp_path / "late", slow, images, [1, 2, 3, 0], TOPICS, REORDER_WINDOW)
    with pytest.warns(SkippedFramesWarning, match=r"1 of 4 frames skipped: 1 images of the first topic "
                                                  r"\(/digit0/image\) came out of order"):
        frames = list(read_bag_frames(bag, TOPICS, fixed_poses=T[0]))
    np.testing.assert_allclose([f.stamp for f in frames], slow[1:], atol=1e-6)


def test_frames_whose_tf_stopped_are_skipped_and_the_sensor_named(tmp_path, recording):
    """digit_2's /tf stops after frame 1: frames more than tf_tolerance past its last transform are skipped (tf2
    would not extrapolate), within it they are read."""
    stamps = 10.0 + np.arange(12) / 30.0
    rng = np.random.default_rng(3)
    T = random_poses((12, 3), rng)
    image = recording[2][0, 0]
    messages = []
    for f, s in enumerate(stamps):
        live = [k for k in range(3) if k < 2 or f <= 1]
        tf = tf_message(TYPESTORE, s, ["world"] * len(live), [FRAMES[k] for k in live], T[f, live])
        messages.append(("/tf", TF_MESSAGE, s, tf))
        for k, topic in enumerate(TOPICS):
            messages.append((topic, IMAGE, s, image_message(TYPESTORE, s, FRAMES[k], image)))
    bag = write_bag(tmp_path / "bag", messages)
    with pytest.warns(SkippedFramesWarning, match=r"3 of 12 frames skipped: sensor 2's TF chain \(frame 'digit_2'\) "
                                                  r"was more than 0.25 s from the frame's stamp in 3, from 10.300 s on"):
        frames = list(read_bag_frames(bag, TOPICS, FRAMES))
    assert len(frames) == 9  # frames 2-8 use the transform of frame 1, up to 0.23 s old
    np.testing.assert_allclose(frames[-1].T_world_sensors[2], T[1, 2], atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(list(read_bag_frames(bag, TOPICS, FRAMES, tf_tolerance=1.0))) == 12


def test_a_pose_bag_may_be_one_mcap_or_db3_file(tmp_path):
    rng = np.random.default_rng(5)
    stamps = 3.0 + np.arange(4) * 0.1
    poses = random_poses((4,), rng)
    for name in ("poses.mcap", "poses.db3"):
        path = write_pose_bag(tmp_path / name, stamps, poses)
        assert path.is_file() and sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(name)) == [name]
        got_stamps, got_poses = read_pose_bag(path)
        np.testing.assert_allclose(got_stamps, stamps, atol=1e-9)
        np.testing.assert_allclose(got_poses, poses, atol=1e-9)
        with pytest.raises(InputError, match=f"{name}: exists already; a bag is written to a new file"):
            write_pose_bag(path, stamps, poses)
    with pytest.raises(InputError, match=r"stamps must be finite seconds >= 0 \(ROS time\), got -1.0 for frame 0"):
        write_pose_bag(tmp_path / "negative", np.array([-1.0, 0.0, 0.1, 0.2]), poses)


def test_a_digit_streamed_at_vga_is_read_at_its_qvga_size(tmp_path, recording):
    """A DIGIT streamed at VGA gives 640 x 480 frames, 480 x 640 once turned: read as the 240 x 320 image of the
    same field of view, with an ImageSizeWarning naming the topic; each pixel repeated 2 x 2 comes back exactly."""
    from tactile6d.data.hdf5 import ImageSizeWarning

    stamps, _, images = recording
    vga = images[0, 0].repeat(2, axis=0).repeat(2, axis=1)
    upright = image_message(TYPESTORE, stamps[0], "digit_0", vga)
    raw = image_message(TYPESTORE, stamps[0], "digit_1", np.ascontiguousarray(np.rot90(vga, -1)))
    bag = write_bag(tmp_path / "bag", [("/vga", IMAGE, stamps[0], upright), ("/raw", IMAGE, stamps[0], raw)])
    with pytest.warns(ImageSizeWarning, match=r"/vga: an image is 480 wide x 640 high: read resized .*averaged down"):
        (frame,) = read_bag_frames(bag, ["/vga"], fixed_poses=np.eye(4)[None])
    np.testing.assert_array_equal(frame.images[0], images[0, 0])
    with pytest.warns(ImageSizeWarning, match=r"/raw: an image is 480 wide x 640 high"):
        (frame,) = read_bag_frames(bag, ["/raw"], fixed_poses=np.eye(4)[None], raw_camera_frames=True)
    np.testing.assert_array_equal(frame.images[0], images[0, 0])
    with pytest.raises(InputError, match=r"/raw: an image is 640 wide x 480 high.*rotated by 90 degrees"):
        list(read_bag_frames(bag, ["/raw"], fixed_poses=np.eye(4)[None]))
