"""The robot description parameters shared by every node that models the arm.

``arm_sim`` moves the arm; ``sim_camera`` renders it, ``integrator`` filters it out of the depth
images and ``nbv_planner`` plans views it can reach. All of them must describe the same robot, so
their config dataclasses derive from :class:`RobotParams` and declare the same parameter names.
"""

from __future__ import annotations

from dataclasses import dataclass

from nbv_prob_cnn.arm.robot import (
    DEFAULT_BASE_XYZ,
    DEFAULT_HAND_FROM_CAMERA_XYZ,
    RobotConfig,
    robot_config,
)
from nbv_prob_cnn.ros.common import param


@dataclass
class RobotParams:
    """Robot description parameters (read-only after start-up); default: the Panda beside the 3DT table."""

    urdf_path: str = param("", "robot URDF (empty = the Panda from pybullet_data)")
    base_xyz: list = param(list(DEFAULT_BASE_XYZ), "root link position in frame_id (m)")
    base_rpy: list = param([0.0, 0.0, 0.0], "root link roll, pitch, yaw (rad)")
    camera_parent: str = param("", "link carrying the camera (empty = panda_hand)")
    camera_xyz: list = param(list(DEFAULT_HAND_FROM_CAMERA_XYZ), "optical frame on the link (m)")
    camera_rpy: list = param([0.0, 0.0, 0.0], "optical frame roll, pitch, yaw on the link (rad)")

    def robot_config(self) -> RobotConfig:
        """The core :class:`~nbv_prob_cnn.arm.robot.RobotConfig` these parameters describe.

        Raises:
            ValueError: a custom URDF without ``camera_parent``, or bad poses.
        """
        return robot_config(
            self.urdf_path, self.base_xyz, self.base_rpy, self.camera_parent, self.camera_xyz, self.camera_rpy
        )
