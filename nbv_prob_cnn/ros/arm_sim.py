"""``arm_sim``: a simulated arm carrying the camera (kinematics only, velocity-limited joints).

Publishes at ``rate_hz`` (names relative to the node namespace, see :mod:`nbv_prob_cnn.ros.names`):

* ``joint_states`` (``sensor_msgs/JointState``: every joint of the URDF, position and velocity)
* ``arm/camera_pose`` (``geometry_msgs/PoseStamped``: the camera_optical pose from forward
  kinematics, in ``frame_id``)

Moves with the service ``arm_sim/move_to_joints`` (``nbv_prob_cnn_msgs/MoveToJoints``: answers
at once with the motion's duration) or the topic ``arm/joint_trajectory``
(``trajectory_msgs/JointTrajectory``: its points in order, each segment at least as long as its
``time_from_start`` difference). Joints move in straight joint-space segments, each joint at most
at ``velocity_scale`` × its URDF velocity limit (:mod:`nbv_prob_cnn.arm.motion`). Unknown joint
names, positions outside the limits and non-finite values are refused with a clear message.

Run: ``nbv node arm_sim --ros-args -p velocity_scale:=0.5`` (default: the Panda beside the 3DT table).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import PoseStamped
from nbv_prob_cnn_msgs.srv import MoveToJoints
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from nbv_prob_cnn.arm.motion import JointMotion
from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.basics.camera import quaternion_from_matrix
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.common import declare_config, param, run_node
from nbv_prob_cnn.ros.robot_params import RobotParams

NODE_NAME = "arm_sim"


@dataclass
class ArmSimConfig(RobotParams):
    """Parameters of ``arm_sim`` (all read-only after start-up): the robot description, then these."""

    frame_id: str = param("world", "frame of the base pose and the camera pose")
    rate_hz: float = param(50.0, "publishing rate", min_value=0.1, max_value=1000.0)
    velocity_scale: float = param(0.5, "fraction of the URDF velocity limits", min_value=0.01, max_value=1.0)
    initial_positions: list = param([0.0], "initial joint positions in URDF order ([0.0] = reference)")


class ArmSim(Node):
    """Integrates velocity-limited joint motion and publishes joint states and the camera pose."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = declare_config(self, ArmSimConfig)  # also sets self.<name> for each parameter
        cfg = self.config
        config = cfg.robot_config()
        scale, initial, rate = cfg.velocity_scale, cfg.initial_positions, cfg.rate_hz
        self.robot = RobotModel(config)
        limits = np.asarray(self.robot.model.velocityLimit, dtype=np.float64) * float(scale)
        if not np.all(np.isfinite(limits) & (limits > 0)):
            raise ValueError("velocity limits: every URDF joint needs a positive <limit velocity=...>")
        q0 = self.robot.reference_q
        if list(initial) != [0.0]:
            q0 = self._checked(self.robot.check_q(np.asarray(initial, dtype=np.float64), "initial_positions"))
        self._lock = threading.Lock()
        self.motion = JointMotion(q0, limits, now=self._now())
        self.joint_pub = self.create_publisher(JointState, names.JOINT_STATES, 10)
        self.pose_pub = self.create_publisher(PoseStamped, names.ARM_CAMERA_POSE, 10)
        self.create_subscription(JointTrajectory, names.ARM_TRAJECTORY, self._on_trajectory, 10)
        self.create_service(MoveToJoints, names.MOVE_TO_JOINTS, self._on_move)
        self.create_timer(1.0 / float(rate), self._publish)
        self.get_logger().info(f"arm_sim ready: joints {self.robot.joint_names}")

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _checked(self, q: np.ndarray) -> np.ndarray:
        if not self.robot.within_limits(q, tol=1e-6):
            names = [n for n, v, lo, hi in zip(self.robot.joint_names, q, self.robot.lower, self.robot.upper,
                                                strict=True) if not lo - 1e-6 <= v <= hi + 1e-6]  # fmt: skip
            raise ValueError(f"joint positions outside the URDF limits: {names}")
        return q

    def _target(self, names, positions, base: np.ndarray) -> np.ndarray:
        if len(names) != len(positions):
            raise ValueError(f"got {len(names)} joint names but {len(positions)} positions")
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate joint names in {list(names)}")
        return self._checked(self.robot.configuration(dict(zip(names, positions, strict=True)), base=base))

    def _on_move(self, request: MoveToJoints.Request, response: MoveToJoints.Response):
        try:
            now = self._now()
            with self._lock:
                goal = self._target(list(request.name), list(request.position), self.motion.goal())
                response.duration_s = self.motion.move_through([goal], now) - now
            response.success = True
        except ValueError as exc:
            response.success = False
            response.message = str(exc)
            self.get_logger().warning(f"move_to_joints: {exc}")
        return response

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        try:
            now = self._now()
            with self._lock:
                base = self.motion.goal()
                waypoints, minimum, previous = [], [], 0.0
                for point in msg.points:
                    base = self._target(list(msg.joint_names), list(point.positions), base)
                    t = point.time_from_start.sec + point.time_from_start.nanosec * 1e-9
                    waypoints.append(base)
                    minimum.append(max(0.0, t - previous))
                    previous = t
                self.motion.move_through(waypoints, now, minimum)
        except ValueError as exc:
            self.get_logger().warning(f"joint_trajectory refused: {exc}")

    def _publish(self) -> None:
        now_msg = self.get_clock().now().to_msg()
        now = now_msg.sec + now_msg.nanosec * 1e-9
        with self._lock:
            q, dq = self.motion.position(now), self.motion.velocity(now)
        joints = JointState()
        joints.header.stamp = now_msg
        joints.name = list(self.robot.joint_names)
        joints.position = [float(v) for v in q]
        joints.velocity = [float(v) for v in dq]
        self.joint_pub.publish(joints)
        pose = self.robot.camera_pose(q)
        msg = PoseStamped()
        msg.header.stamp = now_msg
        msg.header.frame_id = self.frame_id
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in pose[:3, 3])
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in quaternion_from_matrix(pose[:3, :3]))
        self.pose_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    return run_node(ArmSim, args, threads=2)


if __name__ == "__main__":
    raise SystemExit(main())
