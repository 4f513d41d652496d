"""The integrator with ``still_frames_fused:=2``: of the frames a still camera streams it fuses
the first two and skips the rest (counted as ``skipped_still``), the grid's stamp still follows the
newest frame, and the grid is the one an integrator that fuses every frame builds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")
pytest.importorskip("rosbags")
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from geometry_msgs.msg import TransformStamped  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from plane_frames import S, plane_frame  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from test_ros_perception import START_TIMEOUT_S, RosClient, assert_clean_stop, counts, stamp_ns  # noqa: E402
from test_ros_perception import domain_id as perception_domain  # noqa: E402

from nbv_prob_cnn.ros.conversions import msg_to_grid  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

PARAMS = {"pose_source": "topic", "publish_rate_hz": 0.0, "pose_timeout_s": 1.0, "drop_when_behind": False,
          "qos_reliability": "reliable", "queue_size": 20}  # fmt: skip


def down_pose(x: float) -> np.ndarray:
    """Camera 1 m above the floor at (0.74 + x, 0.74), looking down."""
    pose = np.diag([1.0, -1.0, -1.0, 1.0])
    pose[:3, 3] = [0.74 + x, 0.74, 1.0]
    return pose


def test_a_still_camera_is_fused_once_per_pose_and_the_grid_follows_its_stamps(ros_domain, tmp_path: Path) -> None:
    env = ros_domain(perception_domain(11))
    with NodeGraph(env, log_dir=tmp_path) as graph, RosClient(int(env["ROS_DOMAIN_ID"])) as client:
        graph.start_node("integrator", "integrator", {**PARAMS, "still_frames_fused": 2})
        graph.start_node("every_frame", "integrator", PARAMS, namespace="/ref")
        node = client.node
        pubs = {
            ns: (
                node.create_publisher(Image, f"{ns}/camera/depth/image", 20),
                node.create_publisher(CameraInfo, f"{ns}/camera/depth/camera_info", 20),
                node.create_publisher(TransformStamped, f"{ns}/camera/pose", 20),
            )
            for ns in ("", "/ref")
        }
        ref_grids: list[VoxelGrid] = []
        node.create_subscription(VoxelGrid, "/ref/nbv/grid", ref_grids.append, GRID_QOS)
        assert client.spin_until(
            lambda: all(p.get_subscription_count() >= 1 for group in pubs.values() for p in group), START_TIMEOUT_S
        ), "the integrators did not subscribe"
        client.spin_until(lambda: False, 0.5)

        def frame(stamp: int, pose: np.ndarray) -> None:
            cdr = plane_frame(stamp, pose, "cam")
            for image_pub, info_pub, pose_pub in pubs.values():
                pose_pub.publish(cdr.pose)
                info_pub.publish(cdr.info)
                image_pub.publish(cdr.image)

        diagnostics = node.create_client(Trigger, "/integrator/diagnostics")

        def report() -> dict:
            return json.loads(client.call(diagnostics, Trigger.Request()).message)

        def same_as_every_frame(stamp: int) -> np.ndarray:
            grid, _ = msg_to_grid(client.wait_grid(stamp))
            assert client.spin_until(lambda: ref_grids and stamp_ns(ref_grids[-1].header.stamp) >= stamp, 20.0)
            reference, _ = msg_to_grid(ref_grids[-1])
            np.testing.assert_array_equal(grid, reference)
            return grid

        for k in range(1, 6):  # five frames from one pose: two fused, three skipped
            frame(k * S, down_pose(0.0))
        still = same_as_every_frame(5 * S)
        assert counts(still)["occupied"] > 0 and counts(still)["empty"] > 0, counts(still)
        assert client.spin_until(lambda: report()["skipped_still"] == 3, 10.0), report()
        first = report()
        assert first["integrated"] == 2 and first["images"] == 5 and first["dropped_total"] == 0, first
        frame(6 * S, down_pose(0.1))  # the arm moved: fused
        frame(7 * S, down_pose(0.1))
        moved = same_as_every_frame(7 * S)
        assert not np.array_equal(moved, still)
        final = report()
        assert (final["integrated"], final["skipped_still"], final["dropped_total"]) == (4, 3, 0), final
        assert all(graph.alive().values())
        assert_clean_stop(graph)
