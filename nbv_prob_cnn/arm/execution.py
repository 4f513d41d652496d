"""What a joint trajectory controller gets for one planned arm move (no ROS here): the joints it
names and the joint path timed within the robot's limits."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.arm.trajectory import TimedPath, time_parameterise_path


@dataclass(frozen=True)
class TrajectoryLimits:
    """Timing of a joint path: ``velocity_scale`` × the URDF velocity limits, the acceleration
    (rad/s² or m/s²) and jerk (rad/s³ or m/s³) limits and the time between points (s)."""

    velocity_scale: float
    max_acceleration: float
    max_jerk: float
    dt_s: float


def controller_joints(robot: RobotModel, names: Sequence[str]) -> list[str]:
    """The joints a trajectory names: ``names`` without empty entries, or the camera chain's.

    Raises:
        ValueError: a name the robot lacks (named).
    """
    joints = [n for n in names if n] or [robot.joint_names[i] for i in robot.chain]
    unknown = sorted(set(joints) - set(robot.joint_names))
    if unknown:
        raise ValueError(f"controller_joints: {unknown} are not joints of the robot {robot.joint_names}")
    return joints


def timed_joint_path(
    robot: RobotModel,
    q_start: np.ndarray,
    q_goal: np.ndarray,
    limits: TrajectoryLimits,
    waypoints: np.ndarray | None = None,
) -> TimedPath:
    """The joint path from ``q_start`` to ``q_goal`` (straight, or through a planned path's
    ``waypoints``, start and goal included) timed within ``limits``."""
    vmax = np.asarray(robot.model.velocityLimit, dtype=np.float64) * limits.velocity_scale
    points = np.stack([q_start, q_goal]) if waypoints is None else np.asarray(waypoints, dtype=np.float64)
    acceleration, jerk = np.full(vmax.shape, limits.max_acceleration), np.full(vmax.shape, limits.max_jerk)
    return time_parameterise_path(points, vmax, acceleration, jerk, limits.dt_s)
