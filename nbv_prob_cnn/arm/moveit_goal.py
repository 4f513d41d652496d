"""What ``nbv_planner move_mode:=moveit`` asks of MoveIt 2's ``move_group`` for a planned view, with
no ROS here: the ``moveit_msgs/action/MoveGroup`` goal as plain values (:class:`MoveGroupGoal`),
built the way MoveIt's own ``MoveGroupInterface`` builds one, and the names of the
``moveit_msgs/MoveItErrorCodes`` it answers with. ``nbv_prob_cnn.ros.moveit_mover`` only copies these
values into the messages.

* A **pose goal** constrains the goal link (``link``; the camera's optical frame by default) as
  ``kinematic_constraints::constructGoalConstraints(link, pose, tolerance_pos, tolerance_angle)``
  does: one ``PositionConstraint`` (a sphere of radius ``position_tolerance_m`` centred on the
  link's goal position, in the goal frame) and one ``OrientationConstraint`` (the goal orientation,
  ``orientation_tolerance_rad`` about each axis), both of weight 1. MoveIt solves the IK itself.
* A **joint goal** is the configuration our IK found for the view: one ``JointConstraint`` per joint
  of the group, ``joint_tolerance`` above and below, weight 1.

When the goal link is not the camera's frame but a link the camera is fixed on (``panda_hand``,
``tool0``), the link's goal pose is the camera's goal pose times the fixed link→camera transform
of the robot model (:func:`link_from_camera`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

from nbv_prob_cnn.basics.camera import matrix_from_quaternion, quaternion_from_matrix

#: How a view goes to MoveIt: the camera link's pose (MoveIt solves the IK) or our IK's joints.
MoveItGoalType = Literal["pose", "joints"]
MOVEIT_GOAL_TYPES: tuple[MoveItGoalType, ...] = get_args(MoveItGoalType)

#: ``moveit_msgs/MoveItErrorCodes`` (Jazzy, moveit_msgs 2.6): value → constant name.
MOVEIT_ERROR_NAMES: dict[int, str] = {
    1: "SUCCESS",
    0: "UNDEFINED",
    99999: "FAILURE",
    -1: "PLANNING_FAILED",
    -2: "INVALID_MOTION_PLAN",
    -3: "MOTION_PLAN_INVALIDATED_BY_ENVIRONMENT_CHANGE",
    -4: "CONTROL_FAILED",
    -5: "UNABLE_TO_AQUIRE_SENSOR_DATA",
    -6: "TIMED_OUT",
    -7: "PREEMPTED",
    -10: "START_STATE_IN_COLLISION",
    -11: "START_STATE_VIOLATES_PATH_CONSTRAINTS",
    -26: "START_STATE_INVALID",
    -12: "GOAL_IN_COLLISION",
    -13: "GOAL_VIOLATES_PATH_CONSTRAINTS",
    -14: "GOAL_CONSTRAINTS_VIOLATED",
    -27: "GOAL_STATE_INVALID",
    -28: "UNRECOGNIZED_GOAL_TYPE",
    -15: "INVALID_GROUP_NAME",
    -16: "INVALID_GOAL_CONSTRAINTS",
    -17: "INVALID_ROBOT_STATE",
    -18: "INVALID_LINK_NAME",
    -19: "INVALID_OBJECT_NAME",
    -21: "FRAME_TRANSFORM_FAILURE",
    -22: "COLLISION_CHECKING_UNAVAILABLE",
    -23: "ROBOT_STATE_STALE",
    -24: "SENSOR_INFO_STALE",
    -25: "COMMUNICATION_FAILURE",
    -29: "CRASH",
    -30: "ABORT",
    -31: "NO_IK_SOLUTION",
}
MOVEIT_SUCCESS = 1


def moveit_error_text(code: int, message: str = "", source: str = "") -> str:
    """``"GOAL_IN_COLLISION (-12): message [source]"``: a MoveIt error code by name, for people."""
    name = MOVEIT_ERROR_NAMES.get(int(code), "unknown MoveIt error code")
    text = f"{name} ({int(code)})"
    if message:
        text += f": {message}"
    if source:
        text += f" [{source}]"
    return text


@dataclass(frozen=True)
class MoveGroupSettings:
    """The ``move_group`` request's settings (``nbv_planner``'s ``moveit_*`` parameters)."""

    group: str
    link: str  # the goal link of pose goals ("" = the camera's optical frame)
    goal_type: MoveItGoalType = "pose"
    position_tolerance_m: float = 0.01
    orientation_tolerance_rad: float = 0.05
    joint_tolerance: float = 0.01
    planning_time_s: float = 5.0
    planning_attempts: int = 1
    velocity_scaling: float = 0.5
    acceleration_scaling: float = 0.5
    pipeline_id: str = ""
    planner_id: str = ""

    def __post_init__(self) -> None:
        checks = {
            "group": bool(self.group),
            "goal_type": self.goal_type in MOVEIT_GOAL_TYPES,
            "position_tolerance_m": self.position_tolerance_m > 0,
            "orientation_tolerance_rad": self.orientation_tolerance_rad > 0,
            "joint_tolerance": self.joint_tolerance > 0,
            "planning_time_s": self.planning_time_s > 0,
            "planning_attempts": self.planning_attempts >= 1,
            "velocity_scaling": 0 < self.velocity_scaling <= 1,
            "acceleration_scaling": 0 < self.acceleration_scaling <= 1,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"MoveGroup settings: bad {', '.join(bad)} ({self})")


@dataclass(frozen=True)
class PositionGoal:
    """A ``PositionConstraint``: ``link``'s origin inside a sphere of ``radius_m`` around ``centre``."""

    link: str
    centre: np.ndarray  # (3,), goal frame
    radius_m: float


@dataclass(frozen=True)
class OrientationGoal:
    """An ``OrientationConstraint``: ``link``'s orientation (xyzw) within ``tolerance_rad`` per axis."""

    link: str
    quaternion: np.ndarray  # (4,) xyzw, goal frame
    tolerance_rad: float


@dataclass(frozen=True)
class JointGoal:
    """A ``JointConstraint``: ``joint`` at ``position`` ± ``tolerance``."""

    joint: str
    position: float
    tolerance: float


@dataclass(frozen=True)
class MoveGroupGoal:
    """The values of one ``MoveGroup`` goal: ``request`` (a ``MotionPlanRequest`` with one goal
    ``Constraints`` from the current state) and ``planning_options`` (plan and execute)."""

    settings: MoveGroupSettings
    frame: str  # header.frame_id of the constraints
    positions: tuple[PositionGoal, ...] = ()
    orientations: tuple[OrientationGoal, ...] = ()
    joints: tuple[JointGoal, ...] = ()


def link_from_camera(world_from_link: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
    """The fixed link→camera transform (4×4) from both frames' world poses at one configuration."""
    return np.linalg.inv(np.asarray(world_from_link, dtype=np.float64)) @ np.asarray(world_from_camera, np.float64)


def pose_goal(
    settings: MoveGroupSettings,
    frame: str,
    link: str,
    camera_position: np.ndarray,
    camera_quaternion: np.ndarray,
    link_from_cam: np.ndarray | None = None,
) -> MoveGroupGoal:
    """The pose goal of a view: the camera at ``camera_position`` / ``camera_quaternion`` (xyzw, in
    ``frame``), as a goal for ``link`` (fixed on the camera by ``link_from_cam``; None: the link is
    the camera's frame)."""
    position = np.asarray(camera_position, dtype=np.float64).reshape(3)
    quaternion = np.asarray(camera_quaternion, dtype=np.float64).reshape(4)
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quaternion))) or np.linalg.norm(quaternion) < 1e-9:
        raise ValueError(f"MoveGroup pose goal: bad camera pose {position}, {quaternion}")
    if not link:
        raise ValueError("MoveGroup pose goal: no goal link")
    world_from_camera = np.eye(4)
    world_from_camera[:3, :3] = matrix_from_quaternion(quaternion / np.linalg.norm(quaternion))
    world_from_camera[:3, 3] = position
    world_from_link = world_from_camera if link_from_cam is None else world_from_camera @ np.linalg.inv(link_from_cam)
    link_quaternion = np.asarray(quaternion_from_matrix(world_from_link[:3, :3]), dtype=np.float64)
    position_goal = PositionGoal(link, world_from_link[:3, 3].copy(), settings.position_tolerance_m)
    orientation_goal = OrientationGoal(link, link_quaternion, settings.orientation_tolerance_rad)
    return MoveGroupGoal(settings, frame, positions=(position_goal,), orientations=(orientation_goal,))


def joint_goal(settings: MoveGroupSettings, frame: str, names: list[str], positions: list[float]) -> MoveGroupGoal:
    """The joint goal of a view: our IK's configuration of the group's joints ``names``."""
    if len(names) != len(positions) or not names:
        raise ValueError(f"MoveGroup joint goal: {len(names)} joint names for {len(positions)} positions")
    if len(set(names)) != len(names):
        raise ValueError(f"MoveGroup joint goal: duplicate joint names {names}")
    values = [float(v) for v in positions]
    if not all(np.isfinite(values)):
        raise ValueError(f"MoveGroup joint goal: non-finite positions {values}")
    joints = tuple(JointGoal(n, v, settings.joint_tolerance) for n, v in zip(names, values, strict=True))
    return MoveGroupGoal(settings, frame, joints=joints)
