"""The MoveGroup goal values of a planned view (no ROS): pose goals for the camera link or a link the
camera is fixed on, checked against the robot's forward kinematics; joint goals; the error names
against the MoveItErrorCodes definition in msg_defs/."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.arm.moveit_goal import (
    MOVEIT_ERROR_NAMES,
    MoveGroupSettings,
    joint_goal,
    link_from_camera,
    moveit_error_text,
    pose_goal,
)
from nbv_prob_cnn.basics.camera import matrix_from_quaternion, quaternion_from_matrix

DEFINITION = Path(__file__).resolve().parents[2] / "msg_defs" / "moveit_msgs" / "msg" / "MoveItErrorCodes.msg"


def settings(**fields) -> MoveGroupSettings:
    return MoveGroupSettings(**{"group": "panda_arm", "link": "camera_optical", **fields})


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation between two rotation matrices."""
    cosine = (np.trace(a.T @ b) - 1.0) / 2.0
    return float(np.arccos(np.clip(cosine, -1.0, 1.0)))


def test_error_names_are_the_definitions_constants():
    text = DEFINITION.read_text()
    constants = {int(value): name for name, value in re.findall(r"^int32 ([A-Z_]+)=(-?\d+)$", text, re.M)}
    assert len(constants) == 31
    assert constants == MOVEIT_ERROR_NAMES
    assert moveit_error_text(-12, "the goal collides", "ompl") == "GOAL_IN_COLLISION (-12): the goal collides [ompl]"
    assert moveit_error_text(-31) == "NO_IK_SOLUTION (-31)"
    assert moveit_error_text(12345) == "unknown MoveIt error code (12345)"


def test_a_pose_goal_for_the_camera_link_is_the_view_with_its_tolerances():
    s = settings(position_tolerance_m=0.02, orientation_tolerance_rad=0.1)
    quaternion = np.array([0.1, -0.2, 0.3, 0.9])
    goal = pose_goal(s, "world", "camera_optical", [0.4, 0.5, 0.6], quaternion)
    assert goal.frame == "world" and goal.joints == ()
    (position,), (orientation,) = goal.positions, goal.orientations
    assert position.link == orientation.link == "camera_optical"
    np.testing.assert_allclose(position.centre, [0.4, 0.5, 0.6])
    assert position.radius_m == 0.02 and orientation.tolerance_rad == 0.1
    # the same rotation (a quaternion and its negative are one orientation)
    expected = matrix_from_quaternion(quaternion / np.linalg.norm(quaternion))
    assert rotation_angle(matrix_from_quaternion(orientation.quaternion), expected) < 1e-9


def test_a_pose_goal_for_the_hand_puts_the_camera_at_the_view():
    """The camera is fixed on panda_hand: the hand's goal pose is where forward kinematics puts the
    hand when the camera is at the view (a configuration's own poses, not the helper's algebra)."""
    pytest.importorskip("pinocchio")
    from nbv_prob_cnn.arm.robot import RobotModel

    robot = RobotModel()
    fixed = link_from_camera(robot.frame_pose(robot.reference_q, "panda_hand"), robot.camera_pose(robot.reference_q))
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = robot.lower + rng.random(robot.nq) * (robot.upper - robot.lower)
        camera, hand = robot.camera_pose(q), robot.frame_pose(q, "panda_hand")
        goal = pose_goal(settings(link="panda_hand"), "world", "panda_hand", camera[:3, 3],
                         quaternion_from_matrix(camera[:3, :3]), fixed)  # fmt: skip
        np.testing.assert_allclose(goal.positions[0].centre, hand[:3, 3], atol=1e-9)
        assert rotation_angle(matrix_from_quaternion(goal.orientations[0].quaternion), hand[:3, :3]) < 1e-7
        assert goal.positions[0].link == goal.orientations[0].link == "panda_hand"


def test_a_joint_goal_names_each_joint_with_its_tolerance():
    goal = joint_goal(settings(joint_tolerance=0.003), "world", ["j1", "j2"], [0.1, -0.2])
    assert [(j.joint, j.position, j.tolerance) for j in goal.joints] == [("j1", 0.1, 0.003), ("j2", -0.2, 0.003)]
    assert goal.positions == () and goal.orientations == ()


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda: joint_goal(settings(), "world", ["j1", "j2"], [0.1]), "2 joint names for 1"),
        (lambda: joint_goal(settings(), "world", ["j1", "j1"], [0.1, 0.2]), "duplicate"),
        (lambda: joint_goal(settings(), "world", ["j1"], [float("nan")]), "non-finite"),
        (lambda: pose_goal(settings(), "world", "camera_optical", [0, 0, np.inf], [0, 0, 0, 1]), "bad camera pose"),
        (lambda: pose_goal(settings(), "world", "camera_optical", [0, 0, 0], [0, 0, 0, 0]), "bad camera pose"),
        (lambda: pose_goal(settings(), "world", "", [0, 0, 0], [0, 0, 0, 1]), "no goal link"),
        (lambda: settings(group=""), "group"),
        (lambda: settings(goal_type="cartesian"), "goal_type"),
        (lambda: settings(velocity_scaling=0.0), "velocity_scaling"),
        (lambda: settings(position_tolerance_m=-1.0), "position_tolerance_m"),
    ],
)
def test_bad_goals_and_settings_are_refused_by_name(call, words):
    with pytest.raises(ValueError, match=words):
        call()
