"""The view guard in ``nbv_planner``'s Explore action: against a stand-in camera whose grid never
changes, every view changes 0 cells, so with the guard (the default) each pose is ruled out and
the next view is another one; with ``guard_min_cells:=0`` the plan, on the same grid, is the same
pose every time."""

from __future__ import annotations

import os

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from action_msgs.msg import GoalStatus  # noqa: E402
from nbv_prob_cnn_msgs.action import Explore  # noqa: E402
from test_ros_explore import FakeCamera, send, spun_node, wait  # noqa: E402

from nbv_prob_cnn.ros.action_client import LockedActionClient  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs


def _pose_key(pose_stamped) -> tuple:
    p, q = pose_stamped.pose.position, pose_stamped.pose.orientation
    return tuple(round(v, 6) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w))


@pytest.mark.parametrize("guard_min_cells", [-1, 0])
def test_explore_rules_out_views_that_change_nothing(tmp_path, ros_domain, guard_min_cells):
    env = ros_domain(160 + (os.getpid() + guard_min_cells) % 10)  # 160..169: used by no other module
    with spun_node("explore_guard_test") as node:
        camera = FakeCamera(node, delay_s=0.05)
        graph = NodeGraph(env, log_dir=tmp_path / "logs")
        params = {"dataset": "3du", "method": "prob_ig", "in_process": True, "backend": "numpy",
                  "markers_top_k": 1, "guard_min_cells": guard_min_cells}  # fmt: skip
        graph.start_node("nbv_planner", "nbv_planner", params)
        try:
            client = LockedActionClient(node, Explore, "/nbv/explore")
            assert client.wait_for_server(timeout_sec=60.0), "the Explore server did not come up"
            feedback: list = []
            done = wait(send(client, Explore.Goal(max_views=3), feedback).get_result_async(), 120.0)
            assert done.status == GoalStatus.STATUS_SUCCEEDED, done.result.reason_stopped
            poses = [_pose_key(p) for p in done.result.poses]
            assert len(poses) == 3 and camera.moves == 3
            ruled_out = [f.feedback.ruled_out_views for f in feedback]
            if guard_min_cells == 0:  # off: the unchanged grid gives the same best view each time
                assert len(set(poses)) == 1 and ruled_out == [0, 0, 0]
            else:  # 5e-5 of 24^3 cells = 1 cell: each view changed 0, so each pose is ruled out
                assert len(set(poses)) == 3 and ruled_out == [1, 2, 3]
            assert graph.alive() == {"nbv_planner": True}
        finally:
            graph.stop()
