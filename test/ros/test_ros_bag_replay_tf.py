"""A bag posed by TF, as a robot records it (the base on ``/tf``, the camera's mount once on
``/tf_static``), replayed by ``bag_replay`` into the ``integrator`` with its default
``pose_source:=tf``: ``/tf_static`` reaches the TF listener (transient local, as tf2 publishes it), no
frame is lost and the grid is ``nbv integrate``'s of the same bag (the offline TF lookup), cell for
cell."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")
pytest.importorskip("rosbags")
pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("tf2_msgs")

from nbv_prob_cnn_msgs.srv import SaveGrid  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from test_ros_perception import RosClient, assert_clean_stop, log_text  # noqa: E402

from nbv_prob_cnn import cli  # noqa: E402
from nbv_prob_cnn.perception import load_grid  # noqa: E402
from nbv_prob_cnn.perception.bags import (  # noqa: E402
    MSG_TF,
    TOPIC_CAMERA_INFO,
    TOPIC_IMAGE,
    TOPIC_TF,
    TOPIC_TF_STATIC,
    depth_to_image_msg,
    intrinsics_to_camera_info,
    pose_to_transform_msg,
    read_frames,
    typestore,
)
from nbv_prob_cnn.ros.graph import NodeGraph, wait_for  # noqa: E402

pytestmark = pytest.mark.slow  # a multi-process ROS graph

SAMPLE_BAG = Path(__file__).resolve().parents[2] / "bags" / "3dt_seed1000_sample"
FRAMES = 10
#: base -> camera_optical: 0.3 m up, the optical axis along the base's x axis
MOUNT = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0]])


def write_robot_bag(path: Path) -> int:
    """The sample bag's first frames with each camera pose split into world -> base (/tf) and the
    mount (/tf_static, once, first); returns the number of frames."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = typestore()
    frames = [f for _, f in zip(range(FRAMES), read_frames(SAMPLE_BAG), strict=False)]
    tf = store.types[MSG_TF]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}

        def write(topic: str, stamp: int, msg) -> None:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=store)
            writer.write(conns[topic], stamp, store.serialize_cdr(msg, msg.__msgtype__))

        first = frames[0].stamp_ns
        write(TOPIC_TF_STATIC, first, tf(transforms=[pose_to_transform_msg(MOUNT, first, "base", "camera_optical")]))
        for f in frames:
            base = f.pose_4x4 @ np.linalg.inv(MOUNT)
            write(TOPIC_TF, f.stamp_ns, tf(transforms=[pose_to_transform_msg(base, f.stamp_ns, "world", "base")]))
            write(TOPIC_IMAGE, f.stamp_ns, depth_to_image_msg(f.depth_m, f.stamp_ns))
            write(TOPIC_CAMERA_INFO, f.stamp_ns, intrinsics_to_camera_info(f.intrinsics, f.stamp_ns))
    return len(frames)


def test_a_tf_bag_replays_into_the_tf_integrator_without_loss(ros_domain, tmp_path: Path) -> None:
    bag = tmp_path / "robot"
    n = write_robot_bag(bag)
    assert cli.main(["integrate", "--bag", str(bag), "--out", str(tmp_path / "offline.npz")]) == 0
    offline, _, _ = load_grid(tmp_path / "offline.npz")
    env = ros_domain(190 + os.getpid() % 10)  # 190..199: no other test uses these
    with NodeGraph(env, log_dir=tmp_path) as graph:
        graph.start_node("integrator", "integrator", {})  # pose_source tf, fixed_frame world: the defaults
        replay = graph.start_node("bag_replay", "bag_replay", {"bag": str(bag), "rate": 10.0})
        assert wait_for(lambda: replay.poll() is not None, 60.0), log_text(tmp_path, "bag_replay")
        text = log_text(tmp_path, "bag_replay")
        assert replay.returncode == 0, text
        with RosClient(int(env["ROS_DOMAIN_ID"])) as client:
            report = json.loads(
                client.call(client.node.create_client(Trigger, "/integrator/diagnostics"), Trigger.Request()).message
            )
            reply = client.call(
                client.node.create_client(SaveGrid, "/integrator/save"),
                SaveGrid.Request(path=str(tmp_path / "live.npz")),
            )
            assert reply.success, reply.message
        assert_clean_stop(graph)
    line = re.search(r"sent (\d+), integrated (\d+), dropped (\d+) by reason \((.*?)\); received (\d+)", text)
    assert line and line.groups() == (str(n), str(n), "0", "none", str(n)), text[-2000:]
    assert f"{TOPIC_TF_STATIC} 1" in text and f"{TOPIC_TF} {n}" in text, text[-2000:]
    assert report["integrated"] == n and report["dropped_total"] == 0, report
    live, _, _ = load_grid(tmp_path / "live.npz")
    assert np.array_equal(live, offline), f"{int(np.count_nonzero(live != offline))} cells differ"
    assert np.count_nonzero(live == 1) > 0
