"""Bags posed by ``/tf`` (+ ``/tf_static``), as a robot records them: ``read_frames`` looks each image's
frame up in TF at its stamp (chained, interpolated), waits for TF that comes after the image, and says
which images it never posed."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.perception.bags import (
    MSG_TF,
    TOPIC_CAMERA_INFO,
    TOPIC_IMAGE,
    TOPIC_POSE,
    TOPIC_TF,
    TOPIC_TF_STATIC,
    BagError,
    BagWarning,
    BagWriter,
    bag_pose_source,
    depth_to_image_msg,
    intrinsics_to_camera_info,
    pose_to_transform_msg,
    read_frames,
    read_raw_messages,
    typestore,
)
from nbv_prob_cnn.perception.depth_camera import Intrinsics

INTRINSICS = Intrinsics(8, 6, 5.0, 5.0, 3.5, 2.5)
S = 1_000_000_000  # one second in ns


def turn_z(deg: float, xyz=(0.0, 0.0, 0.0)) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    pose = np.eye(4)
    pose[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = xyz
    return pose


#: base -> camera_optical, fixed: 0.3 m up, looking along the base's x axis (optical z forward)
MOUNT = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0]])


def tf_msg(*transforms) -> object:
    """A TFMessage of ``(parent, child, stamp_ns, pose)`` tuples."""
    store = typestore()
    return store.types[MSG_TF](
        transforms=[pose_to_transform_msg(p, t, parent, child) for parent, child, t, p in transforms]
    )


def camera_msgs(stamp: int, frame_id: str = "camera_optical") -> list[tuple[str, object]]:
    depth = np.full((INTRINSICS.height, INTRINSICS.width), 1.5, np.float32)
    return [
        (TOPIC_IMAGE, depth_to_image_msg(depth, stamp, "32FC1", frame_id)),
        (TOPIC_CAMERA_INFO, intrinsics_to_camera_info(INTRINSICS, stamp, frame_id)),
    ]


def write_bag(path: Path, messages: list[tuple[str, object]]) -> Path:
    """A bag of ``(topic, message)`` in this order (log time: the order's index, in ms)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for i, (topic, msg) in enumerate(messages):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=store)
            writer.write(conns[topic], i * 1_000_000, store.serialize_cdr(msg, msg.__msgtype__))
    return path


def test_a_chain_of_tf_is_looked_up_at_the_image_stamp_and_interpolated(tmp_path):
    # the base drives 0.2 m along x and turns 20 deg between 0.9 s and 1.1 s; the camera sits on it (/tf_static);
    # the image at 1.0 s is recorded before the TF sample after it (it waits for it)
    messages = [
        (TOPIC_TF_STATIC, tf_msg(("base", "camera_optical", 0, MOUNT))),
        (TOPIC_TF, tf_msg(("world", "base", 9 * S // 10, turn_z(0.0, (0.0, 0.0, 0.0))))),
        *camera_msgs(S),
        (TOPIC_TF, tf_msg(("world", "base", 11 * S // 10, turn_z(20.0, (0.2, 0.0, 0.0))))),
    ]
    bag = write_bag(tmp_path / "chain", messages)
    assert bag_pose_source(bag) == "tf"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every message forms the frame
        (frame,) = read_frames(bag, strict=True)
    assert frame.stamp_ns == S
    np.testing.assert_allclose(frame.pose_4x4, turn_z(10.0, (0.1, 0.0, 0.0)) @ MOUNT, atol=1e-12)
    # a fixed frame that is not in the tree: nothing is posed, and the warning says why
    with pytest.warns(BagWarning, match=r"1 image\(s\) without a transform from 'map' in /tf at their stamp"):
        assert list(read_frames(bag, fixed_frame="map")) == []


def test_images_that_tf_never_covers_are_named(tmp_path):
    # TF from 2 s on: the image at 1 s is before its oldest sample (given up once TF is 10 s past it); the image
    # at 20 s is after the newest one (still waiting at the end)
    messages = [*camera_msgs(S)]
    messages += [(TOPIC_TF, tf_msg(("world", "camera_optical", t * S, turn_z(t)))) for t in range(2, 13)]
    messages += [*camera_msgs(5 * S), *camera_msgs(20 * S)]
    bag = write_bag(tmp_path / "gaps", messages)
    with pytest.warns(BagWarning, match=r"2 image\(s\) without a transform .* at 20.000000 s: cannot transform"):
        frames = list(read_frames(bag))
    assert [f.stamp_ns for f in frames] == [5 * S]
    np.testing.assert_allclose(frames[0].pose_4x4, turn_z(5.0), atol=1e-12)
    with pytest.raises(BagError, match=r"2 image\(s\) without a transform"):
        read_frames(bag, strict=True)
    # an image without a frame id cannot be looked up
    bag = write_bag(tmp_path / "no_frame", [(TOPIC_TF, tf_msg(("world", "cam", S, np.eye(4)))), *camera_msgs(S, "")])
    with pytest.warns(BagWarning, match="no header.frame_id"):
        assert list(read_frames(bag)) == []


def test_which_poses_a_bag_is_read_by(tmp_path):
    # neither /camera/pose nor /tf: refused, naming both
    bag = write_bag(tmp_path / "none", camera_msgs(S))
    with pytest.raises(BagError, match=r"missing topic\(s\) \['/camera/pose'\] \(the poses: /camera/pose or /tf\)"):
        read_frames(bag)
    with pytest.raises(BagError, match="missing topic"):
        bag_pose_source(bag)
    # both: /camera/pose (the /tf here would put the camera elsewhere)
    pose = turn_z(30.0, (1.0, 2.0, 3.0))
    both = [*camera_msgs(S), (TOPIC_POSE, pose_to_transform_msg(pose, S)),
            (TOPIC_TF, tf_msg(("world", "camera_optical", S, np.eye(4))))]  # fmt: skip
    bag = write_bag(tmp_path / "both", both)
    assert bag_pose_source(bag) == "topic"
    (frame,) = read_frames(bag)
    np.testing.assert_allclose(frame.pose_4x4, pose, atol=1e-12)
    # a transform that is not one: refused, naming the topic and the stamp
    store = typestore()
    msg = tf_msg(("world", "camera_optical", S, np.eye(4)))
    msg.transforms[0].transform.translation = store.types["geometry_msgs/msg/Vector3"](x=math.nan, y=0.0, z=0.0)
    bag = write_bag(tmp_path / "nan", [(TOPIC_TF, msg), *camera_msgs(S)])
    with pytest.raises(BagError, match=f"{TOPIC_TF} at stamp {S}: transform: NaN"):
        read_frames(bag)


def test_the_writer_puts_each_pose_on_tf_before_its_image(tmp_path):
    poses = [turn_z(10.0 * i, (0.1 * i, 0.0, 1.0)) for i in range(3)]
    with BagWriter(tmp_path / "tf", pose_source="tf") as bag:
        for i, pose in enumerate(poses):
            bag.write_frame(S + i * S // 30, np.full((6, 8), 2.0, np.float32), INTRINSICS, pose)
    store = typestore()
    raw = list(read_raw_messages(tmp_path / "tf"))
    assert [m.topic for m in raw] == [TOPIC_TF, TOPIC_IMAGE, TOPIC_CAMERA_INFO] * 3
    for i in range(3):
        tf, image = (store.deserialize_cdr(m.data, m.msgtype) for m in raw[3 * i : 3 * i + 2])
        (transform,) = tf.transforms
        assert (transform.header.frame_id, transform.child_frame_id) == ("world", image.header.frame_id)
        assert image.header.frame_id == "camera_optical" and transform.header.stamp == image.header.stamp
    for frame, pose in zip(read_frames(tmp_path / "tf"), poses, strict=True):
        np.testing.assert_allclose(frame.pose_4x4, pose, atol=1e-12)
    with pytest.raises(ValueError, match="pose_source"):
        BagWriter(tmp_path / "x", pose_source="odom")


def test_a_topic_filter_that_matches_nothing_reads_nothing(tmp_path):
    # rosbags reads every connection when given an empty list: a filter that matches no topic of the bag
    # must read no message (it read the bag's /tf and camera messages, and `nbv view --bag` crashed on them)
    bag = write_bag(tmp_path / "tf", [(TOPIC_TF, tf_msg(("world", "camera_optical", S, turn_z(0.0)))), *camera_msgs(S)])
    for validate in (True, False):
        assert list(read_raw_messages(bag, ["/nosuch"], validate=validate)) == []
        assert list(read_raw_messages(bag, [], validate=validate)) == []
        assert [m.topic for m in read_raw_messages(bag, ["/nosuch", TOPIC_TF], validate=validate)] == [TOPIC_TF]
