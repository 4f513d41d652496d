"""``nbv_planner move_mode:=moveit``: each planned view goes to MoveIt 2's ``move_group`` as a
``moveit_msgs/action/MoveGroup`` goal (``moveit_action``, default ``/move_action``), planned and
executed by MoveIt against its own planning scene.

The goal's values come from :mod:`nbv_prob_cnn.arm.moveit_goal` (a pose goal for the camera link,
or our IK's joint goal; ``moveit_goal_type``); this module copies them into the messages as MoveIt's
``MoveGroupInterface`` fills them (start state = the current state, ``is_diff``; plan and execute).
A goal that is rejected, or whose ``error_code`` is not ``SUCCESS``, raises
:class:`~nbv_prob_cnn.exploration.session.MoveError` with the ``MoveItErrorCodes`` name
(``GOAL_IN_COLLISION (-12): ...``): the exploration reports it in the Explore feedback and tries the
next ranked view. After ``SUCCESS`` the move ends when ``joint_states`` reach the last point of the
executed (else planned) trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from action_msgs.msg import GoalStatus
from moveit_msgs.action import MoveGroup
from moveit_msgs.msg import Constraints, JointConstraint, OrientationConstraint, PositionConstraint
from nbv_prob_cnn_msgs.srv import PlanNextBestView
from rclpy.node import Node
from shape_msgs.msg import SolidPrimitive

from nbv_prob_cnn.arm.arm_session import ArmSession
from nbv_prob_cnn.arm.execution import controller_joints
from nbv_prob_cnn.arm.moveit_goal import (
    MOVEIT_GOAL_TYPES,
    MOVEIT_SUCCESS,
    MoveGroupGoal,
    MoveGroupSettings,
    joint_goal,
    link_from_camera,
    moveit_error_text,
    pose_goal,
)
from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.session import MoveError, PlannedView
from nbv_prob_cnn.ros.action_client import LockedActionClient
from nbv_prob_cnn.ros.conversions import pose_to_arrays
from nbv_prob_cnn.ros.movers import run_action_goal
from nbv_prob_cnn.ros.parameters import param
from nbv_prob_cnn.ros.robot_params import JointStateTracker


@dataclass
class MoveItParams:
    """The ``moveit_*`` parameters of ``nbv_planner`` (``move_mode:=moveit``)."""

    moveit_action: str = param("/move_action", "move_mode moveit: move_group's MoveGroup action")
    moveit_group: str = param("panda_arm", "move_mode moveit: the planning group (the SRDF's arm group)")
    moveit_link: str = param(
        "", "move_mode moveit: the goal link of pose goals, the camera's optical frame or a link it is fixed on "
        "(the camera's goal pose is carried over by the robot model); '' = camera_frame",
    )  # fmt: skip
    moveit_goal_type: str = param(
        "pose", "move_mode moveit: 'pose' (the goal link's pose, MoveIt solves the IK) or 'joints' (our IK's "
        "configuration of the group's joints)", choices=MOVEIT_GOAL_TYPES,
    )  # fmt: skip
    moveit_position_tolerance_m: float = param(
        0.01, "move_mode moveit: pose goal position tolerance (m, sphere radius)", min_value=1e-6, max_value=1.0
    )
    moveit_orientation_tolerance_rad: float = param(
        0.05, "move_mode moveit: pose goal orientation tolerance (rad, about each axis)", min_value=1e-6,
        max_value=3.15,
    )  # fmt: skip
    moveit_joint_tolerance: float = param(0.01, "move_mode moveit: joint goal tolerance (rad or m, above and below)",
                                          min_value=1e-6, max_value=1.0)  # fmt: skip
    moveit_planning_time_s: float = param(5.0, "move_mode moveit: allowed_planning_time (s)", min_value=0.01,
                                          max_value=600.0)  # fmt: skip
    moveit_planning_attempts: int = param(1, "move_mode moveit: num_planning_attempts", min_value=1, max_value=1000)
    moveit_velocity_scaling: float = param(0.5, "move_mode moveit: max_velocity_scaling_factor", min_value=0.001,
                                           max_value=1.0)  # fmt: skip
    moveit_acceleration_scaling: float = param(0.5, "move_mode moveit: max_acceleration_scaling_factor",
                                               min_value=0.001, max_value=1.0)  # fmt: skip
    moveit_pipeline: str = param("", "move_mode moveit: pipeline_id ('' = move_group's default)")
    moveit_planner: str = param("", "move_mode moveit: planner_id ('' = the pipeline's default)")

    def moveit_settings(self, camera_frame: str) -> MoveGroupSettings:
        return MoveGroupSettings(
            self.moveit_group, self.moveit_link or camera_frame, self.moveit_goal_type,  # type: ignore[arg-type]
            self.moveit_position_tolerance_m, self.moveit_orientation_tolerance_rad, self.moveit_joint_tolerance,
            self.moveit_planning_time_s, self.moveit_planning_attempts, self.moveit_velocity_scaling,
            self.moveit_acceleration_scaling, self.moveit_pipeline, self.moveit_planner,
        )  # fmt: skip


def move_group_msg(goal: MoveGroupGoal) -> MoveGroup.Goal:
    """The ``MoveGroup`` goal message of :class:`MoveGroupGoal` values."""
    settings, msg = goal.settings, MoveGroup.Goal()
    request = msg.request
    request.group_name, request.num_planning_attempts = settings.group, settings.planning_attempts
    request.allowed_planning_time = settings.planning_time_s
    request.max_velocity_scaling_factor = settings.velocity_scaling
    request.max_acceleration_scaling_factor = settings.acceleration_scaling
    request.pipeline_id, request.planner_id = settings.pipeline_id, settings.planner_id
    request.workspace_parameters.header.frame_id = goal.frame
    request.start_state.is_diff = True  # from the current state
    constraints = Constraints()
    for p in goal.positions:
        position = PositionConstraint(link_name=p.link, weight=1.0)
        position.header.frame_id = goal.frame
        region = position.constraint_region
        region.primitives = [SolidPrimitive(type=SolidPrimitive.SPHERE, dimensions=[float(p.radius_m)])]
        region.primitive_poses = [region_pose(p.centre)]
        constraints.position_constraints.append(position)
    for o in goal.orientations:
        orientation = OrientationConstraint(link_name=o.link, weight=1.0)
        orientation.header.frame_id = goal.frame
        q = orientation.orientation
        q.x, q.y, q.z, q.w = (float(v) for v in o.quaternion)
        tolerance = float(o.tolerance_rad)
        orientation.absolute_x_axis_tolerance = orientation.absolute_y_axis_tolerance = tolerance
        orientation.absolute_z_axis_tolerance = tolerance
        constraints.orientation_constraints.append(orientation)
    constraints.joint_constraints = [
        JointConstraint(joint_name=j.joint, position=j.position, tolerance_above=j.tolerance,
                        tolerance_below=j.tolerance, weight=1.0)
        for j in goal.joints
    ]  # fmt: skip
    request.goal_constraints = [constraints]
    options = msg.planning_options
    options.plan_only = False
    options.planning_scene_diff.is_diff = options.planning_scene_diff.robot_state.is_diff = True
    return msg


def region_pose(centre: np.ndarray):
    """A ``geometry_msgs/Pose`` at ``centre`` with the identity orientation."""
    from geometry_msgs.msg import Pose

    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in centre)
    pose.orientation.w = 1.0
    return pose


class MoveGroupMover:
    """``move_mode`` moveit: the planned view as a MoveGroup goal (see the module docstring)."""

    def __init__(self, node: Node, params, joints: JointStateTracker, arm: ArmSession, callback_group=None) -> None:
        self._node, self._params, self._joints, self._arm = node, params, joints, arm
        self._settings = params.moveit_settings(params.camera_frame)
        self._client = LockedActionClient(node, MoveGroup, params.moveit_action, callback_group=callback_group)
        robot = arm.robot
        link = self._settings.link
        self._link_from_camera = None
        if self._settings.goal_type == "pose" and link != params.camera_frame:
            # fixed on the camera: the same transform at two configurations
            try:
                transforms = [link_from_camera(robot.frame_pose(q, link), robot.camera_pose(q))
                              for q in (robot.reference_q, (robot.lower + robot.upper) / 2)]  # fmt: skip
            except ValueError as exc:
                raise ValueError(f"moveit_link {link!r}: {exc}") from exc
            if not np.allclose(transforms[0], transforms[1], atol=1e-6):
                raise ValueError(f"moveit_link {link!r}: the camera {params.camera_frame!r} is not fixed on it")
            self._link_from_camera = transforms[0]

    def goal(self, target: PlanNextBestView.Response) -> MoveGroupGoal:
        """The goal values of a planned view."""
        frame = target.best_pose.header.frame_id or self._params.frame_id
        if self._settings.goal_type == "joints":
            q = self._arm.robot.joint_state_configuration(target.joint_goal.name, target.joint_goal.position)
            names = self._group_joints()
            values = [float(q[self._arm.robot.joint_names.index(n)]) for n in names]
            return joint_goal(self._settings, frame, names, values)
        position, quaternion = pose_to_arrays(target.best_pose.pose)
        return pose_goal(self._settings, frame, self._settings.link, position, quaternion, self._link_from_camera)

    def _group_joints(self) -> list[str]:
        """The joints of the camera's chain (a joint goal names the group's joints: the SRDF's arm group
        is the camera's chain, the gripper apart)."""
        return controller_joints(self._arm.robot, [""])

    def move(self, planned: PlannedView[PlanNextBestView.Response], interrupt: Interrupt) -> int:
        params, action = self._params, self._params.moveit_action
        try:
            goal = move_group_msg(self.goal(planned.target))
        except ValueError as exc:
            raise MoveError(f"MoveGroup goal: {exc}") from exc
        outcome, sent = run_action_goal(self._node, self._client, goal, action, params.move_timeout_s,
                                        self._settings.planning_time_s + params.move_timeout_s, interrupt,
                                        "MoveGroup", missing=" (is move_group running?)",
                                        rejected=" (see move_group's log)")  # fmt: skip
        result = outcome.result
        code = int(result.error_code.val)
        if code != MOVEIT_SUCCESS or outcome.status != GoalStatus.STATUS_SUCCEEDED:
            text = moveit_error_text(code, result.error_code.message, result.error_code.source)
            raise MoveError(f"MoveIt {text} (status {outcome.status})")
        trajectory = result.executed_trajectory.joint_trajectory
        if not trajectory.points:
            trajectory = result.planned_trajectory.joint_trajectory
        if not trajectory.points:
            raise MoveError(f"MoveIt {moveit_error_text(code)} without a trajectory: where the arm went is unknown")
        last = dict(zip(trajectory.joint_names, trajectory.points[-1].positions, strict=True))
        try:
            current, _ = self._joints.current()
            q_goal = self._arm.robot.configuration(last, base=current)
            tolerance = max(params.joint_tolerance, self._settings.joint_tolerance)
            return self._joints.wait_until(q_goal, tolerance, sent, params.move_timeout_s, interrupt)
        except (ValueError, TimeoutError) as exc:
            raise MoveError(f"after MoveIt's SUCCESS: {exc}") from exc
