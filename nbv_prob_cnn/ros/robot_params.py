"""The robot description parameters shared by every node that models the arm, and the
conversions between ``sensor_msgs/JointState`` and configuration vectors.

``arm_sim`` moves the arm; ``sim_camera`` renders it, ``integrator`` filters it out of the depth
images and ``nbv_planner`` / ``gain_server`` plan views it can reach. All of them must describe the
same robot, so their config dataclasses derive from :class:`RobotParams` and declare the same
parameter names.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from sensor_msgs.msg import JointState

from nbv_prob_cnn.arm.robot import (
    DEFAULT_BASE_XYZ,
    DEFAULT_HAND_FROM_CAMERA_XYZ,
    RobotConfig,
    RobotModel,
    robot_config,
)
from nbv_prob_cnn.perception.messages import stamp_ns
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


@dataclass
class ArmViewParams(RobotParams):
    """The robot description plus the switch and the scene prior of nodes that check views with the arm."""

    use_arm: bool = param(False, "only views the arm reaches collision-free (IK + collision checks)")
    free_above_m: float = param(
        0.25, "tabletop prior: unknown cells at or above this height (m) do not block the arm; < 0 = all block",
        min_value=-1.0, max_value=100.0,
    )  # fmt: skip

    def free_above(self) -> float | None:
        """The prior as the core takes it (None: every unknown cell blocks)."""
        return None if self.free_above_m < 0 else float(self.free_above_m)


def joint_state_msg(robot: RobotModel, q: np.ndarray | None) -> JointState:
    """``sensor_msgs/JointState`` of a configuration (every joint, URDF order); empty for None."""
    msg = JointState()
    if q is not None:
        msg.name = list(robot.joint_names)
        msg.position = [float(v) for v in robot.check_q(q)]
    return msg


class JointStateTracker:
    """The latest ``joint_states`` of a robot, converted on arrival (subscription callback
    :meth:`on_joint_state`); a message with wrong names is kept as its error, so the next request
    reports it instead of planning from a stale configuration."""

    def __init__(self, robot: RobotModel) -> None:
        self.robot = robot
        self._condition = threading.Condition()
        self._q: np.ndarray | None = None
        self._stamp_ns = -1
        self._error = ""

    def on_joint_state(self, msg: JointState) -> str:
        """Store one message; returns its error ("" when it was valid)."""
        try:
            q, error = self.robot.joint_state_configuration(msg.name, msg.position), ""
        except ValueError as exc:
            q, error = None, str(exc)
        with self._condition:
            self._q, self._error = q, error
            self._stamp_ns = stamp_ns(msg.header.stamp)
            self._condition.notify_all()
        return error

    def current(self) -> tuple[np.ndarray, int]:
        """The latest configuration and its stamp (ns).

        Raises:
            ValueError: no joint state yet, or the latest one had wrong names/values.
        """
        with self._condition:
            return self._checked()

    def current_or(self, default: np.ndarray) -> np.ndarray:
        """The latest configuration, or ``default`` before any joint state arrived.

        Raises:
            ValueError: the latest joint state had wrong names/values.
        """
        with self._condition:
            return default if self._q is None and not self._error else self._checked()[0]

    def _checked(self) -> tuple[np.ndarray, int]:
        if self._error:
            raise ValueError(self._error)
        if self._q is None:
            raise ValueError("no joint state received yet on joint_states")
        return self._q.copy(), self._stamp_ns

    def wait_for_first(self, timeout_s: float) -> None:
        """Wait until the first joint state (valid or not) has arrived.

        Raises:
            TimeoutError: none within ``timeout_s``.
        """
        with self._condition:
            if not self._condition.wait_for(lambda: self._q is not None or bool(self._error), timeout_s):
                raise TimeoutError(f"no joint state received on joint_states within {timeout_s:.0f} s")

    def wait_until(self, goal: np.ndarray, tolerance: float, min_stamp_ns: int, timeout_s: float) -> int:
        """Wait until a joint state stamped at or after ``min_stamp_ns`` is within ``tolerance``
        (max abs difference, rad or m) of ``goal``; returns its stamp (ns).

        Raises:
            ValueError: a joint state with wrong names/values arrives meanwhile.
            TimeoutError: not reached in time.
        """

        def done() -> bool:
            if self._error:
                return True
            if self._q is None or self._stamp_ns < min_stamp_ns:
                return False
            return float(np.max(np.abs(self._q - goal))) <= tolerance

        with self._condition:
            if not self._condition.wait_for(done, timeout_s):
                q = "none" if self._q is None else f"{float(np.max(np.abs(self._q - goal))):.4f} away"
                raise TimeoutError(f"joint_states did not reach the joint goal within {timeout_s:.0f} s (last: {q})")
            return self._checked()[1]
