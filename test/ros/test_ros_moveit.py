"""``nbv_planner move_mode:=moveit`` end to end: the Explore action hands each view to a MoveGroup
action server (the test's :class:`move_group_check.MoveGroupCheck`, which checks each goal as
``move_group`` does and executes it through ``arm_sim``'s FollowJointTrajectory controller), each
node in its own process but the check. No MoveIt binary runs here (docs/robot.md, "With MoveIt 2")."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("control_msgs")
pytest.importorskip("moveit_msgs.action")
pytest.importorskip("pinocchio")

from explore_goals import explore_client, explore_succeeds  # noqa: E402
from move_group_check import MoveGroupCheck  # noqa: E402
from moveit_msgs.msg import MoveItErrorCodes  # noqa: E402
from nbv_prob_cnn_msgs.action import Explore  # noqa: E402
from test_ros_arm_planning import ARM_PLANNER, GraphBench, SeeingIntegrator, assert_pose_close, scene  # noqa: E402
from test_ros_explore import spun_node  # noqa: E402

from nbv_prob_cnn.arm.robot import RobotModel  # noqa: E402
from nbv_prob_cnn.basics.camera import matrix_from_quaternion  # noqa: E402
from nbv_prob_cnn.ros.conversions import pose_to_arrays  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

E = MoveItErrorCodes
_counter = iter(range(1000))
MOVEIT_PLANNER = {**ARM_PLANNER, "move_mode": "moveit", "moveit_group": "panda_arm"}


@pytest.fixture
def ros(tmp_path, ros_domain):
    """Domains 120..123 (this module only); arm_sim running; the bench's grid and a SeeingIntegrator."""
    env = ros_domain(120 + (os.getpid() + next(_counter)) % 4)
    with spun_node("moveit_test") as node:
        bench = GraphBench(node)
        graph = NodeGraph(env, log_dir=tmp_path / "logs")
        graph.start_node("arm_sim", "arm_sim", {"velocity_scale": 1.0, "rate_hz": 50.0})
        SeeingIntegrator(node, bench)
        yield node, bench, graph
        graph.stop()


def test_pose_goals_go_to_move_group_and_a_failure_is_reported_by_name(ros):
    """Pose goals of the camera link; the check answers the first with GOAL_IN_COLLISION: the
    feedback names it, the next ranked view is tried, and the two views taken put arm_sim's camera
    where the goals asked."""
    node, bench, graph = ros
    robot = RobotModel()
    check = MoveGroupCheck(node, robot, answers=(E.GOAL_IN_COLLISION,))
    graph.start_node("nbv_planner", "nbv_planner", {**MOVEIT_PLANNER, "moveit_velocity_scaling": 0.8})
    done, feedback = explore_succeeds(explore_client(node), Explore.Goal(max_views=2), 400.0)
    assert done.result.views == 2 and done.result.failed_executions == 1, done.result.reason_stopped
    fbs = [m.feedback for m in feedback]
    assert [fb.executed for fb in fbs] == [False, True, True]
    assert "GOAL_IN_COLLISION (-12)" in fbs[0].execution_error and "injected by the test" in fbs[0].execution_error
    assert check.answered == [E.GOAL_IN_COLLISION, E.SUCCESS, E.SUCCESS]
    assert len(check.goals) == 3
    for fb, goal in zip(fbs, check.goals, strict=True):
        request = goal.request
        assert request.group_name == "panda_arm" and request.max_velocity_scaling_factor == pytest.approx(0.8)
        (constraints,) = request.goal_constraints
        (position,), (orientation,) = constraints.position_constraints, constraints.orientation_constraints
        assert position.link_name == orientation.link_name == "camera_optical"
        centre = position.constraint_region.primitive_poses[0].position
        view_position, view_quaternion = pose_to_arrays(fb.pose.pose)
        np.testing.assert_allclose([centre.x, centre.y, centre.z], view_position, atol=1e-9)
        o = orientation.orientation
        rotation = matrix_from_quaternion(np.array([o.x, o.y, o.z, o.w]))
        assert np.allclose(rotation, matrix_from_quaternion(view_quaternion), atol=1e-9)
    rejected, taken = (np.concatenate(pose_to_arrays(fb.pose.pose)) for fb in fbs[:2])
    assert not np.allclose(rejected, taken)  # the next ranked view, not the same one again
    # arm_sim's camera at the last view, within the goal's tolerances (0.01 m, 0.05 rad)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and "pose" not in bench.latest:
        time.sleep(0.1)
    camera = bench.latest["pose"].pose
    np.testing.assert_allclose(pose_to_arrays(camera)[0], pose_to_arrays(fbs[-1].pose.pose)[0], atol=0.011)
    assert (bench.state == -1).sum() < (scene() == -1).sum()  # the views saw something


def test_joint_goals_are_our_ik_and_a_wrong_group_is_reported_by_name(ros):
    """moveit_goal_type joints: the goal's joint constraints are the planned configuration of the
    arm's seven joints. Then a planner with a group move_group does not have: each goal comes back
    INVALID_GROUP_NAME, named in the feedback, until max_failed_executions stops the exploration."""
    node, bench, graph = ros
    robot = RobotModel()
    check = MoveGroupCheck(node, robot)
    first = NodeGraph(graph.env, log_dir=graph.log_dir / "joints")
    first.start_node("nbv_planner", "nbv_planner", {**MOVEIT_PLANNER, "moveit_goal_type": "joints"})
    try:
        done, feedback = explore_succeeds(explore_client(node), Explore.Goal(max_views=1), 400.0)
    finally:
        first.stop()
    assert done.result.views == 1, done.result.reason_stopped
    fb = feedback[-1].feedback
    assert fb.executed
    (constraints,) = check.goals[0].request.goal_constraints
    assert not constraints.position_constraints and not constraints.orientation_constraints
    planned = dict(zip(fb.joint_goal.name, fb.joint_goal.position, strict=True))
    joints = {j.joint_name: j for j in constraints.joint_constraints}
    assert sorted(joints) == sorted(robot.joint_names[:7])
    for name, joint in joints.items():
        assert joint.position == pytest.approx(planned[name], abs=1e-12)
        assert joint.tolerance_above == joint.tolerance_below == pytest.approx(0.01)
    assert_pose_close(robot.camera_pose(robot.configuration(planned)), *pose_to_arrays(fb.pose.pose))

    with NodeGraph(graph.env, log_dir=graph.log_dir / "wrong_group") as planners:
        planners.start_node("nbv_planner", "nbv_planner", {**MOVEIT_PLANNER, "moveit_group": "manipulator",
                                                           "max_failed_executions": 2})  # fmt: skip
        done, feedback = explore_succeeds(explore_client(node), Explore.Goal(max_views=3), 400.0)
    assert done.result.views == 0 and done.result.failed_executions == 2, done.result.reason_stopped
    errors = [m.feedback.execution_error for m in feedback]
    assert len(errors) == 2 and all("INVALID_GROUP_NAME (-15)" in e for e in errors), errors
    assert check.answered[1:] == [E.INVALID_GROUP_NAME, E.INVALID_GROUP_NAME]
