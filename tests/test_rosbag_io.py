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
    with pytest.raises(InputError, match=r"/rotated: an image is 320 wide x 240 high.*rotated by 90 degrees.*np.rot90"):
        list(read_bag_frames(bag, ["/rotated"], fixed_poses=np.eye(4)[None]))
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
    with pytest.warns(SkippedFramesWarning, match=r"1 of 4 frames skipped.*within 0.02 s of the first topic's "
                                                  r"\(/digit0/image\)"):
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
    with pytest.raises(InputError, match=r"exactly one of sensor_frames"):
        read_bag_frames(bag, TOPICS)
    with pytest.raises(InputError, match=r"exactly one of sensor_frames"):
        read_bag_frames(bag, TOPICS, FRAMES, fixed_poses=T[0])
    with pytest.raises(InputError, match=r"an image topic is given twice"):
        read_bag_frames(bag, TOPICS[:2] + TOPICS[:1], FRAMES)
    with pytest.raises(InputError, match=r"2 sensor frames for 3 image topics"):
        read_bag_frames(bag, TOPICS, FRAMES[:2])
    with pytest.raises(InputError, match=r"fixed_poses has shape \(2, 4, 4\), expected \(3, 4, 4\)"):
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
