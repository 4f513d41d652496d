"""Issue 18, "frames lost silently": ``bag_replay`` and ``integrator`` with their default
parameters (only ``pose_source:=topic``: the bag carries its poses on ``/camera/pose``) lose no
frame, even at 10x the recorded rate on a loaded machine, and the replay's closing line accounts
for every frame (``sent N, integrated M, dropped K by reason``). The grid equals ``nbv integrate``
of the same bag (the offline core path), cell for cell.

Before the fix the replay did not wait for subscribers, was paced by bag time only and the
integrator's best-effort queue of 5 and ``drop_when_behind`` lost frames without a count.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")
pytest.importorskip("rosbags")
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from nbv_prob_cnn_msgs.srv import SaveGrid  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from test_ros_perception import RosClient, assert_clean_stop, log_text  # noqa: E402

from nbv_prob_cnn import cli  # noqa: E402
from nbv_prob_cnn.perception import load_grid  # noqa: E402
from nbv_prob_cnn.perception.bags import read_frames  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, wait_for  # noqa: E402

pytestmark = pytest.mark.slow  # a multi-process ROS graph

REPO = Path(__file__).resolve().parents[2]
SAMPLE_BAG = REPO / "bags" / "3dt_seed1000_sample"
#: Busy loops that keep both cores loaded while the graph runs.
BURNER = "import time\nend = time.monotonic() + 120\nwhile time.monotonic() < end: pass"


def test_default_replay_is_lossless_on_a_loaded_machine(ros_domain, tmp_path: Path) -> None:
    frames = list(read_frames(SAMPLE_BAG))
    assert cli.main(["integrate", "--bag", str(SAMPLE_BAG), "--out", str(tmp_path / "offline.npz")]) == 0
    offline, _, _ = load_grid(tmp_path / "offline.npz")
    env = ros_domain(220 + os.getpid() % 4)  # 220..223: no other test uses these
    burners = [subprocess.Popen([sys.executable, "-c", BURNER]) for _ in range(2)]
    try:
        with NodeGraph(env, log_dir=tmp_path) as graph:
            graph.start_node("integrator", "integrator", {"pose_source": "topic"})
            # started at once: the replay waits for the integrator's subscriptions by itself
            replay = graph.start_node("bag_replay", "bag_replay", {"bag": str(SAMPLE_BAG), "rate": 10.0})
            assert wait_for(lambda: replay.poll() is not None, 60.0), log_text(tmp_path, "bag_replay")
            text = log_text(tmp_path, "bag_replay")
            assert replay.returncode == 0, text
            with RosClient(int(env["ROS_DOMAIN_ID"])) as client:
                diagnostics = client.node.create_client(Trigger, "/integrator/diagnostics")
                report = json.loads(client.call(diagnostics, Trigger.Request()).message)
                reply = client.call(
                    client.node.create_client(SaveGrid, "/integrator/save"),
                    SaveGrid.Request(path=str(tmp_path / "live.npz")),
                )
                assert reply.success, reply.message
            assert_clean_stop(graph)
    finally:
        for burner in burners:
            burner.kill()
            burner.wait()
    n = len(frames)
    # the replay's own account of every frame
    line = re.search(r"sent (\d+), integrated (\d+), dropped (\d+) by reason \((.*?)\); received (\d+)", text)
    assert line, text
    assert line.groups() == (str(n), str(n), "0", "none", str(n)), line.group(0)
    # ... agrees with the integrator's
    assert report["images"] == report["integrated"] == n, report
    assert report["dropped_total"] == 0 and report["pending"] == 0, report
    with np.load(tmp_path / "live.npz") as saved:
        assert int(saved["frames"]) == n
        live = saved["grid"]
    assert np.array_equal(live, offline), f"{int(np.count_nonzero(live != offline))} cells differ"


def test_replay_without_subscribers_fails_clearly(ros_domain, tmp_path: Path) -> None:
    env = ros_domain(224 + os.getpid() % 2)  # 224..225
    with NodeGraph(env, log_dir=tmp_path) as graph:
        replay = graph.start_node("bag_replay", "bag_replay", {"bag": str(SAMPLE_BAG), "wait_timeout_s": 1.0})
        assert wait_for(lambda: replay.poll() is not None, 20.0)
        assert_clean_stop(graph, expected={"bag_replay": 1})
    text = log_text(tmp_path, "bag_replay")
    assert "fewer than 1 subscriber(s)" in text and "start the integrator first" in text, text
    assert "sent 0 frame(s)" in text or "published 0 message(s)" in text, text


def test_reset_counts_the_images_waiting_for_their_pose(ros_domain, tmp_path: Path) -> None:
    """An image still waiting for its pose when the grid is reset is counted under ``reset`` (it
    used to vanish uncounted) and is no longer ``pending``."""
    from sensor_msgs.msg import CameraInfo, Image

    from nbv_prob_cnn.perception import Intrinsics
    from nbv_prob_cnn.perception.bags import (
        MSG_CAMERA_INFO,
        MSG_IMAGE,
        TOPIC_CAMERA_INFO,
        TOPIC_IMAGE,
        depth_to_image_msg,
        intrinsics_to_camera_info,
        typestore,
    )

    env = ros_domain(220 + os.getpid() % 4)
    store = typestore()
    intrinsics = Intrinsics.from_hfov(64, 48, 60.0)
    stamp = 5_000_000_000
    with NodeGraph(env, log_dir=tmp_path) as graph:
        graph.start_node("integrator", "integrator", {"pose_source": "topic", "pose_timeout_s": 60.0})
        with RosClient(int(env["ROS_DOMAIN_ID"])) as client:
            image = client.node.create_publisher(Image, TOPIC_IMAGE, 10)
            info = client.node.create_publisher(CameraInfo, TOPIC_CAMERA_INFO, 10)
            assert client.spin_until(lambda: image.get_subscription_count() and info.get_subscription_count(), 40.0)
            client.spin_until(lambda: False, 0.5)
            diagnostics = client.node.create_client(Trigger, "/integrator/diagnostics")

            def report() -> dict:
                return json.loads(client.call(diagnostics, Trigger.Request()).message)

            info.publish(bytes(store.serialize_cdr(intrinsics_to_camera_info(intrinsics, stamp), MSG_CAMERA_INFO)))
            depth = depth_to_image_msg(np.full(intrinsics.shape, 0.6, np.float32), stamp, "16UC1")
            image.publish(bytes(store.serialize_cdr(depth, MSG_IMAGE)))  # no pose: it waits
            assert client.spin_until(lambda: report()["images"] == 1, 10.0), report()
            assert report()["pending"] == 1 and report()["dropped"]["reset"] == 0
            reply = client.call(client.node.create_client(Trigger, "/integrator/reset"), Trigger.Request())
            assert reply.success and "1 waiting frame(s) discarded" in reply.message, reply.message
            after = report()
            assert after["pending"] == 0 and after["dropped"]["reset"] == 1 and after["integrated"] == 0, after
        assert_clean_stop(graph)
