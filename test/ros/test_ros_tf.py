"""The integrator poses depth images by TF (``pose_source:=tf``, the default), as beside a real
robot: ``/tf_static`` world -> base and the camera mount, ``/tf`` base -> camera_link sampled
around the image stamps, images in the optical frame. The grid equals the one a second
integrator builds from the hand-computed poses on ``/camera/pose``; an image whose TF comes late
is held and integrated; images whose frame is unknown, in another tree or outside the TF
history are dropped and counted under their reason. And the grid reaches a subscriber with the
default QoS (volatile) that starts after the last frame, within 2 s."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")
pytest.importorskip("rosbags")
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("tf2_msgs")

from geometry_msgs.msg import TransformStamped  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from plane_frames import S, plane_frame  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from test_ros_perception import (  # noqa: E402
    START_TIMEOUT_S,
    RosClient,
    assert_clean_stop,
    counts,
    log_text,
    stamp_ns,
)
from test_ros_perception import domain_id as perception_domain  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from nbv_prob_cnn.ros.conversions import msg_to_grid, time_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, wait_for  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402
from nbv_prob_cnn.ros.tf_listener import TF_QOS, TF_STATIC_QOS  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

GRID_PARAMS = {"publish_rate_hz": 10.0, "pose_timeout_s": 1.0, "diagnostics_period_s": 0.2}


def transform(parent: str, child: str, stamp: int, xyz, xyzw=(0.0, 0.0, 0.0, 1.0)) -> TransformStamped:
    msg = TransformStamped()
    msg.header.frame_id, msg.header.stamp, msg.child_frame_id = parent, time_msg(stamp), child
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = (float(v) for v in xyz)
    r.x, r.y, r.z, r.w = (float(v) for v in xyzw)
    return msg


def hand_pose(x: float) -> np.ndarray:
    """world <- camera_optical by hand: base at (0.74, 0.74, 0); camera_link at (x, 0, 1.0) in the
    base; the optical frame turned 180° about the link's x axis (z looks down, y along -y)."""
    pose = np.diag([1.0, -1.0, -1.0, 1.0])
    pose[:3, 3] = [0.74 + x, 0.74, 1.0]
    return pose


class Publishers:
    """Images and camera_infos for the TF integrator (plain topics) and the reference (``/ref``)."""

    def __init__(self, client: RosClient) -> None:
        node = client.node
        self.image = {ns: node.create_publisher(Image, f"{ns}/camera/depth/image", 10) for ns in ("", "/ref")}
        self.info = {ns: node.create_publisher(CameraInfo, f"{ns}/camera/depth/camera_info", 10) for ns in ("", "/ref")}
        self.ref_pose = node.create_publisher(TransformStamped, "/ref/camera/pose", 10)
        self.tf = node.create_publisher(TFMessage, "/tf", TF_QOS)
        self.tf_static = node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)

    def all(self) -> list:
        return [*self.image.values(), *self.info.values(), self.ref_pose, self.tf, self.tf_static]

    def frame(self, stamp: int, frame_id: str = "camera_optical") -> None:
        """A frame to be posed by TF: the image and camera_info, no pose."""
        cdr = plane_frame(stamp, np.eye(4), frame_id)
        self.info[""].publish(cdr.info)
        self.image[""].publish(cdr.image)

    def reference_frame(self, stamp: int, pose: np.ndarray) -> None:
        """The reference's frame, with its pose on ``/ref/camera/pose``."""
        cdr = plane_frame(stamp, pose, "camera_optical")
        self.ref_pose.publish(cdr.pose)
        self.info["/ref"].publish(cdr.info)
        self.image["/ref"].publish(cdr.image)


def test_integrator_poses_images_by_tf(ros_domain, tmp_path: Path) -> None:
    env = ros_domain(perception_domain(6))
    with NodeGraph(env, log_dir=tmp_path) as graph, RosClient(int(env["ROS_DOMAIN_ID"])) as client:
        graph.start_node("integrator", "integrator", GRID_PARAMS)
        graph.start_node("ref_integrator", "integrator", {**GRID_PARAMS, "pose_source": "topic"}, namespace="/ref")
        out = Publishers(client)
        ref_grids: list[VoxelGrid] = []
        client.node.create_subscription(VoxelGrid, "/ref/nbv/grid", ref_grids.append, GRID_QOS)
        assert client.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in out.all()), START_TIMEOUT_S), (
            "the integrators did not subscribe"
        )
        assert out.image[""].get_subscription_count() == 1  # the reference is not on the plain topics
        client.spin_until(lambda: False, 0.5)
        diagnostics = client.node.create_client(Trigger, "/integrator/diagnostics")

        def report() -> dict:
            return json.loads(client.call(diagnostics, Trigger.Request()).message)

        def same_grid_as_reference(stamp: int) -> None:
            grid, _ = msg_to_grid(client.wait_grid(stamp))
            assert client.spin_until(lambda: ref_grids and stamp_ns(ref_grids[-1].header.stamp) >= stamp, 20.0)
            reference, _ = msg_to_grid(ref_grids[-1])
            assert counts(grid)["occupied"] > 0 and counts(grid)["empty"] > 0, counts(grid)
            np.testing.assert_array_equal(grid, reference)

        # the robot's static frames, then base -> camera_link at 10 s and 11 s (0.2 m apart along x)
        out.tf_static.publish(TFMessage(transforms=[
            transform("world", "base", 0, (0.74, 0.74, 0.0)),
            transform("camera_link", "camera_optical", 0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
            transform("odom", "lidar", 0, (0.0, 0.0, 0.5)),
        ]))  # fmt: skip
        out.tf.publish(TFMessage(transforms=[transform("base", "camera_link", 10 * S, (-0.1, 0.0, 1.0))]))
        out.tf.publish(TFMessage(transforms=[transform("base", "camera_link", 11 * S, (0.1, 0.0, 1.0))]))
        client.spin_until(lambda: False, 0.3)
        # an image half-way: the camera is interpolated to x = 0 (the reference: the hand-computed pose)
        out.frame(10 * S + S // 2)
        out.reference_frame(10 * S + S // 2, hand_pose(0.0))
        same_grid_as_reference(10 * S + S // 2)

        # an image before its TF: held, then integrated when the TF comes 0.3 s later
        out.frame(12 * S)
        client.spin_until(lambda: False, 0.3)
        out.tf.publish(TFMessage(transforms=[transform("base", "camera_link", 12 * S, (0.2, 0.0, 1.0))]))
        out.reference_frame(12 * S, hand_pose(0.2))
        same_grid_as_reference(12 * S)
        first = report()
        assert first["integrated"] == 2 and first["dropped_total"] == 0, first

        # images that cannot be posed: each dropped after pose_timeout_s under its reason
        cases = [
            ("ir_optical", 13 * S, "tf_unknown_frame", "source frame 'ir_optical' does not exist"),
            ("lidar", 14 * S, "tf_not_connected", "'lidar' is in the tree of 'odom', 'world' in the tree of"),
            ("camera_optical", 5 * S, "tf_extrapolation", "5.000 s before its oldest sample (10.000000 s)"),
            ("camera_optical", 15 * S, "tf_extrapolation", "3.000 s after its newest sample (12.000000 s)"),
        ]
        for frame_id, stamp, reason, text in cases:
            dropped = report()["dropped"][reason]
            out.frame(stamp, frame_id)
            assert client.spin_until(lambda r=reason, d=dropped: report()["dropped"][r] == d + 1, 10.0), (
                reason, report(), log_text(tmp_path, "integrator")[-2000:],
            )  # fmt: skip
            assert text in report()["last_drop"][reason], (text, report()["last_drop"])
        final = report()
        assert final["integrated"] == 2 and final["dropped_total"] == 4, final
        assert "poses by TF" in log_text(tmp_path, "integrator")
        assert all(graph.alive().values())
        assert_clean_stop(graph)


def test_a_default_qos_subscriber_gets_the_grid(ros_domain, tmp_path: Path) -> None:
    """A subscriber with rclpy's default QoS (reliable, volatile, depth 10) that starts after the
    last frame receives the current grid within 2 s (the integrator republishes it)."""
    env = ros_domain(perception_domain(7))
    with NodeGraph(env, log_dir=tmp_path) as graph, RosClient(int(env["ROS_DOMAIN_ID"])) as client:
        graph.start_node("integrator", "integrator", GRID_PARAMS)
        out = Publishers(client)
        assert client.spin_until(
            lambda: all(p.get_subscription_count() >= 1 for p in (out.image[""], out.info[""], out.tf_static)),
            START_TIMEOUT_S,
        ), "the integrator did not subscribe"
        client.spin_until(lambda: False, 0.5)
        out.tf_static.publish(TFMessage(transforms=[transform("world", "camera_optical", 0, (0.74, 0.74, 1.0),
                                                              (1.0, 0.0, 0.0, 0.0))]))  # fmt: skip
        client.spin_until(lambda: False, 0.3)
        out.frame(3 * S)
        latest, _ = msg_to_grid(client.wait_grid(3 * S))  # the transient-local subscriber has it
        client.spin_until(lambda: False, 1.0)  # the last frame is long gone
        late: list[VoxelGrid] = []
        start = time.monotonic()
        client.node.create_subscription(VoxelGrid, "/nbv/grid", late.append, 10)  # the default QoS
        assert client.spin_until(lambda: bool(late), 2.0), "no grid within 2 s on a default-QoS subscription"
        elapsed = time.monotonic() - start
        assert stamp_ns(late[0].header.stamp) == 3 * S
        np.testing.assert_array_equal(msg_to_grid(late[0])[0], latest)
        assert elapsed <= 2.0
        assert wait_for(lambda: all(graph.alive().values()), 1.0)
        assert_clean_stop(graph)


def test_sim_camera_on_the_arm_publishes_only_image_and_camera_info(ros_domain, tmp_path: Path) -> None:
    """On the arm (follow_arm, pose_source tf) sim_camera renders at the newest TF pose of its optical
    frame, stamps each frame with that transform's stamp and publishes no pose; the free camera
    broadcasts its pose on /tf, at its frames' stamps."""
    env = ros_domain(perception_domain(8))
    with NodeGraph(env, log_dir=tmp_path) as graph, RosClient(int(env["ROS_DOMAIN_ID"])) as client:
        small = {"width": 32, "height": 24, "rate_hz": 10.0}
        graph.start_node("sim_camera", "sim_camera", {**small, "follow_arm": True})
        graph.start_node("free_camera", "sim_camera", {**small, "camera_frame": "free_optical"}, namespace="/free")
        node = client.node
        images: list[Image] = []
        node.create_subscription(Image, "/camera/depth/image", images.append, 10)
        broadcast: list[TransformStamped] = []
        free_images: list[Image] = []
        node.create_subscription(TFMessage, "/tf", lambda m: broadcast.extend(m.transforms), TF_QOS)
        node.create_subscription(Image, "/free/camera/depth/image", free_images.append, 10)
        tf = node.create_publisher(TFMessage, "/tf", TF_QOS)
        assert client.spin_until(lambda: tf.get_subscription_count() >= 2, START_TIMEOUT_S)
        assert client.spin_until(lambda: len(free_images) >= 2, START_TIMEOUT_S), "the free camera sent nothing"
        assert images == []  # no camera pose in TF yet: no frame
        # the arm's link chain, as arm_sim / robot_state_publisher publish it
        stamps = [node.get_clock().now().nanoseconds + k * S // 10 for k in range(3)]
        for stamp in stamps:
            tf.publish(TFMessage(transforms=[transform("world", "camera_optical", stamp, (0.74, 0.2, 0.8),
                                                       (1.0, 0.0, 0.0, 0.0))]))  # fmt: skip
            client.spin_until(lambda: False, 0.15)
        assert client.spin_until(lambda: bool(images), 10.0), log_text(tmp_path, "sim_camera")[-1500:]
        client.spin_until(lambda: False, 0.3)
        assert {stamp_ns(i.header.stamp) for i in images} <= set(stamps)  # each frame at a TF stamp
        assert stamp_ns(images[-1].header.stamp) == stamps[-1]
        assert images[-1].header.frame_id == "camera_optical"
        assert node.count_publishers("/camera/pose") == 0  # a camera driver publishes no pose
        assert node.count_publishers("/free/camera/pose") == 1
        recent = {stamp_ns(i.header.stamp) for i in free_images[-3:]}
        client.spin_until(lambda: False, 0.5)  # their /tf messages may still be queued here
        pairs = {(t.header.frame_id, t.child_frame_id, stamp_ns(t.header.stamp)) for t in broadcast}
        assert {("world", "free_optical", stamp) for stamp in recent} <= pairs  # a /tf sample per frame
        assert all(graph.alive().values())
        assert_clean_stop(graph)


def test_the_arm_graph_needs_only_tf(ros_domain, tmp_path: Path) -> None:
    """arm_sim (the robot driver: /tf, /tf_static, joint_states) and sim_camera on the arm (the
    camera driver: Image + CameraInfo in the optical frame) give the integrator posed frames: no
    pose topic between them, and no frame dropped for want of TF."""
    env = ros_domain(perception_domain(9))
    with NodeGraph(env, log_dir=tmp_path) as graph, RosClient(int(env["ROS_DOMAIN_ID"])) as client:
        graph.start_node("arm_sim", "arm_sim", {"rate_hz": 50.0})
        graph.start_node("sim_camera", "sim_camera", {"follow_arm": True, "rate_hz": 5.0, "width": 64, "height": 48})
        graph.start_node("integrator", "integrator", GRID_PARAMS)
        grid, _ = msg_to_grid(client.wait_grid(1, timeout_s=START_TIMEOUT_S + 60.0))
        assert counts(grid)["occupied"] > 0, counts(grid)
        # no pose topic between the robot side and our nodes: nobody publishes /camera/pose, nobody
        # but this test could read arm_sim's own arm/camera_pose
        assert client.node.count_publishers("/camera/pose") == 0
        assert client.node.count_subscribers("/arm/camera_pose") == 0
        diagnostics = client.node.create_client(Trigger, "/integrator/diagnostics")

        def tf_drops(report: dict) -> dict:
            return {k: v for k, v in report["dropped"].items() if k.startswith("tf_")}

        # frames that came before the integrator had matched arm_sim's /tf_static may be dropped
        # (counted by reason, as on a real robot); once TF flows, none is
        # those early frames are counted once their pose_timeout_s (1 s) has passed: wait it out
        client.spin_until(lambda: False, 1.5)
        first = json.loads(client.call(diagnostics, Trigger.Request()).message)
        client.spin_until(lambda: False, 3.0)  # sim_camera at 5 Hz: about 15 more frames
        later = json.loads(client.call(diagnostics, Trigger.Request()).message)
        assert later["integrated"] > first["integrated"] >= 1, (first, later)
        assert tf_drops(later) == tf_drops(first), (first, later)
        assert "poses by TF" in log_text(tmp_path, "integrator")
        assert all(graph.alive().values())
        assert_clean_stop(graph)
