"""A plan that falls back to a view near the camera is counted where the user sees it: the Explore
feedback's ``fallback``, the result's ``fallbacks`` and the planner's log (issue 46, item 5). The arm
starts on one side of a pillar; the 5 views ranked (``arm_top_k``), those that see the unknown patch
on the other side best, are all beyond the arm's reach (no IK solution), so the plan ranks again
near the camera."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("control_msgs")
pytest.importorskip("pinocchio")

from explore_goals import explore_succeeds  # noqa: E402
from nbv_prob_cnn_msgs.action import Explore  # noqa: E402
from test_ros_arm_planning import GEOMETRY, GraphBench  # noqa: E402
from test_ros_arm_trajectory import start_trajectory_graph  # noqa: E402
from test_ros_explore import spun_node  # noqa: E402

from nbv_prob_cnn.arm.robot import RobotModel  # noqa: E402
from nbv_prob_cnn.basics.grid import OCCUPIED, UNKNOWN  # noqa: E402
from nbv_prob_cnn.ros.conversions import pose_to_arrays  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

_counter = iter(range(1000))


@pytest.fixture
def ros(tmp_path, ros_domain):
    """Domains 124..127 (this module only); a client node spun in a background thread."""
    env = ros_domain(124 + (os.getpid() + next(_counter)) % 4)
    with spun_node("fallback_test") as node:
        graph = NodeGraph(env, log_dir=tmp_path / "logs")
        yield node, graph
        graph.stop()


def test_a_plan_that_falls_back_near_the_camera_is_counted(ros):
    node, graph = ros
    robot = RobotModel()
    q_start, halfway, q_far = (robot.reference_q.copy() for _ in range(3))
    q_start[0], halfway[0], q_far[0] = -0.9, 0.0, 0.9
    bench = GraphBench(node)
    state = np.zeros(GEOMETRY.shape, dtype=np.int8)
    state[:, :, 0] = OCCUPIED  # the floor
    pillar = GEOMETRY.containing_cell(robot.camera_pose(halfway)[:3, 3][None])[0][0]
    state[pillar[0] - 3 : pillar[0] + 4, pillar[1] - 3 : pillar[1] + 4, : pillar[2] + 3] = OCCUPIED
    far = GEOMETRY.containing_cell(robot.camera_pose(q_far)[:3, 3][None])[0][0]
    state[max(far[0] - 4, 0) : far[0] + 5, far[1] - 4 : far[1] + 5, 1:8] = UNKNOWN  # what the views look at
    bench.state = state
    bench.joints = (robot.joint_names, q_start)
    # the 5 best views only (in this scene all out of reach), straight paths only
    _, client = start_trajectory_graph(node, graph, bench, robot, reject=0, arm_path_timeout_s=0.0, arm_top_k=5)
    done, feedback = explore_succeeds(client, Explore.Goal(max_views=1), 300.0)
    assert done.result.views == 1, done.result.reason_stopped
    assert done.result.fallbacks == 1
    fb = feedback[-1].feedback
    assert fb.executed and fb.fallback
    # the fallback's view: within arm_fallback_radius_m (0.25 m) of the camera where the arm stood
    start_camera = robot.camera_pose(q_start)[:3, 3]
    assert np.linalg.norm(pose_to_arrays(fb.pose.pose)[0] - start_camera) <= 0.25 + 1e-9
    log = (graph.log_dir / "nbv_planner.log").read_text()
    assert "view 0 (fallback after 5 checked: 5 unreachable)" in log  # what the first pass found
    assert "5 checked of 5 candidates (0 camera-blocked skipped, 5 unreachable" in log  # the first pass
    near = re.search(r"near the camera: (\d+) checked of", log)  # and the second, in the arm check's summary
    assert near is not None, log
    # the view line's count covers both passes (the response's arm_checked)
    assert re.search(rf"view 0 \(fallback[^)]*\): .*IK\+collision [\d.]+ \({5 + int(near[1])} checked\)", log), log
