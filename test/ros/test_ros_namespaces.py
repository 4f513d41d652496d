"""Names are relative: with no namespace they are the documented absolute names, and two
graphs under different namespaces run side by side in one domain without meeting."""

from __future__ import annotations

import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import RankViews  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.ros import names  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, call_with_resend, node_command, wait_for  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

GEOMETRY = GridGeometry((0.0, 0.0, 0.0), 0.02, (24, 24, 24))
DOCUMENTED = {
    "GRID": "/nbv/grid",
    "NEXT_BEST_VIEW": "/nbv/next_best_view",
    "MARKERS": "/nbv/markers",
    "DEPTH_IMAGE": "/camera/depth/image",
    "CAMERA_INFO": "/camera/depth/camera_info",
    "CAMERA_POSE": "/camera/pose",
    "GOAL_POSE": "/camera/goal_pose",
    "PLAN": "/nbv/plan",
    "COMPLETE": "/nbv/complete",
    "RANK_VIEWS": "/nbv/rank_views",
    "EVALUATE_VIEWS": "/nbv/evaluate_views",
    "MOVE_TO": "/sim_camera/move_to",
    "INTEGRATOR_RESET": "/integrator/reset",
    "INTEGRATOR_SAVE": "/integrator/save",
    "INTEGRATOR_DIAGNOSTICS": "/integrator/diagnostics",
    "EXPLORE": "/nbv/explore",
}


def test_names_resolve_to_the_documented_defaults_and_follow_a_namespace():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=110)
    try:
        plain = rclpy.create_node("plain", context=context)
        spaced = rclpy.create_node("spaced", namespace="/robot1", context=context)
        for constant, absolute in DOCUMENTED.items():
            name = getattr(names, constant)
            assert not name.startswith("/"), f"{constant} is absolute"
            assert plain.resolve_topic_name(name) == absolute
            assert spaced.resolve_topic_name(name) == "/robot1" + absolute
    finally:
        rclpy.shutdown(context=context)
    assert node_command("gain_server", namespace="/robot1")[3:] == ["--ros-args", "-r", "__ns:=/robot1"]


def room(low: int, high: int) -> np.ndarray:
    state = np.full(GEOMETRY.shape, -1, dtype=np.int8)
    state[low:high, low:high, low:high] = 0
    return state


@pytest.mark.slow
def test_two_namespaced_graphs_in_one_domain(tmp_path, ros_domain):
    env = ros_domain(111 + os.getpid() % 9)  # 111..119: shared only with test_ros_arm
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("namespace_test", context=context)
    graph = NodeGraph(env, log_dir=tmp_path / "logs")
    try:
        for ns in ("/robot1", "/robot2"):
            graph.start_node(f"gain_server{ns.replace('/', '_')}", "gain_server",
                             {"dataset": "3du", "backend": "numpy"}, namespace=ns)  # fmt: skip
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def rank(ns: str):
            client = node.create_client(RankViews, f"{ns}/{names.RANK_VIEWS}")
            try:  # a fresh client: its first request may be lost while DDS matches it, so resend
                return call_with_resend(client, RankViews.Request(method="prob_ig", top_k=1), 60.0, executor=executor)
            finally:
                node.destroy_client(client)

        # only robot1 gets a grid: robot2's server has none, robot1's ranks views in its room
        robot1 = node.create_publisher(VoxelGrid, f"/robot1/{names.GRID}", GRID_QOS)
        robot1.publish(grid_to_msg(room(4, 10), GEOMETRY))
        assert wait_for(lambda: rank("/robot1").success, 30.0, 0.3), "robot1 never got its grid"
        reply = rank("/robot2")
        assert not reply.success and "no grid" in reply.message
        # robot2's own grid (another room) gives robot2 its own answer
        robot2 = node.create_publisher(VoxelGrid, f"/robot2/{names.GRID}", GRID_QOS)
        robot2.publish(grid_to_msg(room(14, 20), GEOMETRY))
        assert wait_for(lambda: rank("/robot2").success, 30.0, 0.3), "robot2 never got its grid"
        for ns, (low, high) in (("/robot1", (4, 10)), ("/robot2", (14, 20))):
            p = rank(ns).ranked[0].pose.pose.position
            cell, inside = GEOMETRY.containing_cell(np.array([p.x, p.y, p.z]))
            assert inside and all(low <= c < high for c in cell), f"{ns} planned outside its own room: {cell}"
        assert all(graph.alive().values())
    finally:
        graph.stop()
        node.destroy_node()
        rclpy.shutdown(context=context)
