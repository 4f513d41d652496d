"""``arm_sim``: a simulated arm carrying the camera, standing in for a robot driver (kinematics
only, velocity-limited joints).

What a real arm's driver graph publishes (names relative to the node namespace, see
:mod:`nbv_prob_cnn.ros.names`):

* ``robot_description`` (``std_msgs/String``, reliable + transient local, as
  ``robot_state_publisher``): the robot's URDF with the camera's optical frame ``camera_frame``
  fixed on ``camera_parent`` and the root placed in ``world_frame`` (``base_xyz`` / ``base_rpy``).
  ``package://`` URIs of a ``urdf_path`` / ``robot_description`` stay as they are (the readers
  resolve them); the default Panda's meshes are absolute paths;
* ``joint_states`` (``sensor_msgs/JointState``) at ``rate_hz``: the arm's joints in one message and
  the ``gripper_joints`` in another (as separate arm and gripper drivers), same stamp;
* ``/tf`` (``tf2_msgs/TFMessage``): every movable joint's parent → child link transform at the
  joint states' stamp, and ``/tf_static`` (transient local) the fixed joints, camera mount and base
  included, as ``robot_state_publisher`` would;
* ``arm_controller/follow_joint_trajectory`` (``control_msgs/FollowJointTrajectory``, name
  ``controller_action``), served as a ``joint_trajectory_controller`` does: a goal must name
  exactly the arm's joints (the gripper is not the arm controller's), its positions within the
  URDF limits, each segment within the URDF velocity limits and its times increasing, else it
  is rejected; it then runs, with feedback (desired / actual / error), aborts with
  ``PATH_TOLERANCE_VIOLATED`` when a ``path_tolerance`` is exceeded and with
  ``GOAL_TOLERANCE_VIOLATED`` when the joints are not within ``goal_tolerance`` (default
  ``default_goal_tolerance``) of the last point by its time + ``goal_time_tolerance`` (default
  ``default_goal_time_s``), and succeeds with ``SUCCESSFUL``.

The arm moves in straight joint-space segments between a trajectory's points, each joint at most
at ``velocity_scale`` × its URDF velocity limit (:mod:`nbv_prob_cnn.arm.motion`): a trajectory
faster than that lags behind and fails its goal tolerance, as an overloaded real arm would. A
timed path sampled densely (``nbv_planner move_mode:=trajectory``: a straight or OMPL-planned
joint path, :func:`~nbv_prob_cnn.arm.trajectory.time_parameterise_path`) is thus run on the path
itself, the planned path's corners included.

Also (our own, for ``sim_camera`` and the older move modes): ``arm/camera_pose``
(``geometry_msgs/PoseStamped``, the optical frame by forward kinematics), the service
``arm_sim/move_to_joints`` (``nbv_prob_cnn_msgs/MoveToJoints``) and the topic
``arm/joint_trajectory`` (``trajectory_msgs/JointTrajectory``).

Run: ``nbv node arm_sim --ros-args -p velocity_scale:=0.5`` (default: the Panda beside the 3DT table).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import PoseStamped, TransformStamped
from nbv_prob_cnn_msgs.srv import MoveToJoints
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from nbv_prob_cnn.arm.description import UrdfJoint, mount_camera, read_description, resolve_package_uris, urdf_joints
from nbv_prob_cnn.arm.motion import JointMotion
from nbv_prob_cnn.arm.robot import RobotModel, panda_urdf, pose_from_xyz_rpy
from nbv_prob_cnn.arm.trajectory import (
    GOAL_TOLERANCE_VIOLATED,
    PATH_TOLERANCE_VIOLATED,
    SUCCESSFUL,
    TrajectoryError,
    check_trajectory,
    tolerance_violation,
)
from nbv_prob_cnn.basics.camera import quaternion_from_matrix
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.parameters import declare_config, param
from nbv_prob_cnn.ros.robot_params import (
    BUILTIN_PANDA,
    DESCRIPTION_QOS,
    ROBOT_DESCRIPTION,
    RobotParams,
    description_config,
    xacro_arguments,
)
from nbv_prob_cnn.ros.runtime import run_node, shutdown_interrupt

NODE_NAME = "arm_sim"
#: ``/tf_static`` keeps its messages for late joiners (tf2's static broadcaster QoS).
TF_STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Execution loop period of a FollowJointTrajectory goal (s).
EXECUTION_PERIOD_S = 0.02


@dataclass
class ArmSimConfig(RobotParams):
    """Parameters of ``arm_sim`` (all read-only after start-up): the robot (``robot_description``
    text, else ``urdf_path``, else the Panda; placed by ``base_xyz``/``base_rpy`` in
    ``world_frame``, the camera by ``camera_xyz``/``camera_rpy`` on ``camera_parent``), then these."""

    rate_hz: float = param(50.0, "publishing rate of joint_states and /tf", min_value=0.1, max_value=1000.0)
    velocity_scale: float = param(0.5, "fraction of the URDF velocity limits", min_value=0.01, max_value=1.0)
    initial_positions: list = param([0.0], "initial joint positions in URDF order ([0.0] = reference)")
    gripper_joints: list = param(
        ["panda_finger_joint1", "panda_finger_joint2"],
        "joints published in their own joint_states message and not part of the arm controller (names the "
        "robot lacks are left out)",
    )  # fmt: skip
    controller_action: str = param("arm_controller/follow_joint_trajectory", "FollowJointTrajectory action name")
    default_goal_tolerance: float = param(0.01, "goal position tolerance when a goal gives none (rad or m)",
                                          min_value=0.0, max_value=10.0)  # fmt: skip
    default_goal_time_s: float = param(1.0, "goal_time_tolerance when a goal gives none (s)", min_value=0.0,
                                       max_value=600.0)  # fmt: skip


def _transform(parent: str, child: str, pose: np.ndarray, stamp) -> TransformStamped:
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id, msg.child_frame_id = parent, child
    t = msg.transform.translation
    t.x, t.y, t.z = (float(v) for v in pose[:3, 3])
    r = msg.transform.rotation
    r.x, r.y, r.z, r.w = (float(v) for v in quaternion_from_matrix(pose[:3, :3]))
    return msg


class ArmSim(Node):
    """Integrates velocity-limited joint motion; publishes the description, joint states and TF;
    serves FollowJointTrajectory."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = declare_config(self, ArmSimConfig, mirror=False)
        cfg = self.config
        self.description = self._description(cfg)
        dirs = [d for d in cfg.package_dirs if d]
        urdf = resolve_package_uris(self.description, dirs)
        self.robot = RobotModel(
            description_config(urdf, dirs, cfg.world_frame, cfg.base_xyz, cfg.base_rpy, cfg.camera_frame, "",
                               cfg.camera_xyz, cfg.camera_rpy)
        )  # fmt: skip
        self.joints = urdf_joints(urdf)
        limits = np.asarray(self.robot.model.velocityLimit, dtype=np.float64)
        if not np.all(np.isfinite(limits) & (limits > 0)):
            raise ValueError("velocity limits: every URDF joint needs a positive <limit velocity=...>")
        self.velocity_limits = limits
        q0 = self.robot.reference_q
        if list(cfg.initial_positions) != [0.0]:
            q0 = self._checked(self.robot.check_q(np.asarray(cfg.initial_positions, dtype=np.float64),
                                                  "initial_positions"))  # fmt: skip
        names_ = self.robot.joint_names
        self.gripper = [n for n in cfg.gripper_joints if n in names_]
        self.arm_joints = [n for n in names_ if n not in self.gripper]
        self._lock = threading.Lock()
        self.motion = JointMotion(q0, limits * float(cfg.velocity_scale), now=self._now())
        self._goal_lock = threading.Lock()
        self._active_goal = None
        self.joint_pub = self.create_publisher(JointState, names.JOINT_STATES, 10)
        self.pose_pub = self.create_publisher(PoseStamped, names.ARM_CAMERA_POSE, 10)
        self._posed_q: np.ndarray | None = None  # the configuration the cached transforms are of
        self._moving_tf: list[TransformStamped] = []
        self._camera_pose: PoseStamped | None = None
        self.tf_pub = self.create_publisher(TFMessage, "/tf", 100)
        self.tf_static_pub = self.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
        self.description_pub = self.create_publisher(String, ROBOT_DESCRIPTION, DESCRIPTION_QOS)
        self.description_pub.publish(String(data=self.description))
        self._publish_static()
        group = ReentrantCallbackGroup()
        self.create_subscription(JointTrajectory, names.ARM_TRAJECTORY, self._on_trajectory, 10)
        self.create_service(MoveToJoints, names.MOVE_TO_JOINTS, self._on_move)
        self._action = ActionServer(
            self, FollowJointTrajectory, cfg.controller_action, execute_callback=self._execute,
            goal_callback=self._check_goal, handle_accepted_callback=self._accept,
            cancel_callback=lambda _: CancelResponse.ACCEPT, callback_group=group,
        )  # fmt: skip
        # the state is broadcast from a thread of its own, as a controller manager's loop does: a
        # 50 Hz executor timer would make rclpy rebuild the wait set over the action server, the
        # services and the parameter services 50 times a second (a quarter of a core measured)
        self._stop_broadcast = threading.Event()
        self._broadcast_errors = 0
        self._broadcaster = threading.Thread(
            target=self._broadcast_loop, args=(1.0 / float(cfg.rate_hz),), name="joint_state_broadcast", daemon=True
        )
        self._broadcaster.start()
        self.get_logger().info(
            f"arm_sim ready: arm joints {self.arm_joints}, gripper {self.gripper}; "
            f"{self.get_namespace().rstrip('/')}/{cfg.controller_action}"
        )

    @staticmethod
    def _description(cfg: ArmSimConfig) -> str:
        """The published description: the robot with the camera mounted and the base placed."""
        if cfg.robot_description or (cfg.urdf_path and cfg.urdf_path != BUILTIN_PANDA):
            # xacro expanded, package:// kept as a driver publishes it (the readers resolve it)
            text = read_description(cfg.robot_description, cfg.urdf_path, [d for d in cfg.package_dirs if d],
                                    xacro_arguments(cfg.xacro_args), resolve=False)  # fmt: skip
            parent = cfg.camera_parent
            if not parent:
                raise ValueError("camera_parent: required with a custom URDF (the link that carries the camera)")
        else:
            text, parent = panda_urdf()[0].read_text(), cfg.camera_parent or "panda_hand"
        return mount_camera(
            text, parent, pose_from_xyz_rpy(cfg.camera_xyz, cfg.camera_rpy), cfg.camera_frame, cfg.world_frame,
            pose_from_xyz_rpy(cfg.base_xyz, cfg.base_rpy),
        )  # fmt: skip

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _checked(self, q: np.ndarray) -> np.ndarray:
        if not self.robot.within_limits(q, tol=1e-6):
            names_ = [n for n, v, lo, hi in zip(self.robot.joint_names, q, self.robot.lower, self.robot.upper,
                                                 strict=True) if not lo - 1e-6 <= v <= hi + 1e-6]  # fmt: skip
            raise ValueError(f"joint positions outside the URDF limits: {names_}")
        return q

    def _target(self, joint_names, positions, base: np.ndarray) -> np.ndarray:
        if len(joint_names) != len(positions):
            raise ValueError(f"got {len(joint_names)} joint names but {len(positions)} positions")
        if len(set(joint_names)) != len(joint_names):
            raise ValueError(f"duplicate joint names in {list(joint_names)}")
        return self._checked(self.robot.configuration(dict(zip(joint_names, positions, strict=True)), base=base))

    # -- our own move interfaces ---------------------------------------------------------------
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

    # -- FollowJointTrajectory ----------------------------------------------------------------
    def _validate(self, goal: FollowJointTrajectory.Goal) -> tuple[list[str], np.ndarray, np.ndarray]:
        """(joint names, times, positions) of a goal a controller runs.

        Raises:
            TrajectoryError: the controller refuses it (error code and reason).
        """
        trajectory = goal.trajectory
        points = list(trajectory.points)
        joint_names = list(trajectory.joint_names)
        times = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in points]
        positions = [list(p.positions) for p in points]
        robot = self.robot
        with self._lock:
            now = robot.joint_positions(self.motion.position(self._now()))
        lower = dict(zip(robot.joint_names, robot.lower, strict=True))
        upper = dict(zip(robot.joint_names, robot.upper, strict=True))
        vmax = dict(zip(robot.joint_names, self.velocity_limits, strict=True))
        check_trajectory(joint_names, self.arm_joints, times, positions, lower, upper, vmax, now)
        return joint_names, np.asarray(times), np.asarray(positions)

    def _check_goal(self, goal: FollowJointTrajectory.Goal) -> GoalResponse:
        try:
            self._validate(goal)
        except TrajectoryError as exc:
            self.get_logger().warning(f"follow_joint_trajectory: rejected (error code {exc.code}): {exc}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _accept(self, goal_handle) -> None:
        """A new goal preempts the running one (as joint_trajectory_controller)."""
        with self._goal_lock:
            if self._active_goal is not None and self._active_goal.is_active:
                self._active_goal.abort()
            self._active_goal = goal_handle
        goal_handle.execute()

    def _execute(self, goal_handle) -> FollowJointTrajectory.Result:
        result = FollowJointTrajectory.Result()
        goal: FollowJointTrajectory.Goal = goal_handle.request
        try:
            joint_names, times, positions = self._validate(goal)  # the arm may have moved since acceptance
        except TrajectoryError as exc:
            result.error_code, result.error_string = exc.code, str(exc)
            goal_handle.abort()
            return result
        index = [self.robot.joint_names.index(n) for n in joint_names]
        start_time = self._now()
        with self._lock:
            base = self.motion.position(start_time)
            waypoints = []
            for point in positions:
                q = base.copy()
                q[index] = point
                waypoints.append(q)
            self.motion.move_through(waypoints, start_time, list(np.diff(np.r_[0.0, times])))
            start_q = base[index]
        path_tol = {t.name: t.position for t in goal.path_tolerance}
        goal_tol = dict.fromkeys(joint_names, self.config.default_goal_tolerance)
        goal_tol.update({t.name: t.position for t in goal.goal_tolerance if t.position != 0})
        goal_time = (
            goal.goal_time_tolerance.sec + goal.goal_time_tolerance.nanosec * 1e-9 or self.config.default_goal_time_s
        )
        end = start_time + float(times[-1])
        feedback = FollowJointTrajectory.Feedback(joint_names=joint_names)
        shutdown = shutdown_interrupt(self)
        while True:
            now = self._now()
            if not goal_handle.is_active:  # preempted by a newer goal
                result.error_code, result.error_string = SUCCESSFUL, "preempted by a newer goal"
                return result
            if goal_handle.is_cancel_requested:
                self._hold(now)  # stop where it is
                goal_handle.canceled()
                result.error_string = "canceled"
                return result
            if shutdown.is_set():  # as a joint_trajectory_controller deactivated mid-goal: abort, hold
                self._hold(now)
                result.error_string = "arm_sim is shutting down"
                goal_handle.abort()
                return result
            desired = _desired(times, positions, start_q, now - start_time)
            with self._lock:
                actual = self.motion.position(now)[index]
            feedback.header.stamp = self.get_clock().now().to_msg()
            feedback.desired = JointTrajectoryPoint(positions=[float(v) for v in desired])
            feedback.actual = JointTrajectoryPoint(positions=[float(v) for v in actual])
            feedback.error = JointTrajectoryPoint(positions=[float(v) for v in desired - actual])
            goal_handle.publish_feedback(feedback)
            if now <= end:
                violation = tolerance_violation(joint_names, actual, desired, path_tol)
                if violation:
                    return self._abort(goal_handle, result, PATH_TOLERANCE_VIOLATED, violation, now)
            else:
                violation = tolerance_violation(joint_names, actual, positions[-1], goal_tol)
                if not violation:
                    goal_handle.succeed()
                    result.error_code = SUCCESSFUL
                    return result
                if now > end + goal_time:
                    return self._abort(goal_handle, result, GOAL_TOLERANCE_VIOLATED, violation, now)
            time.sleep(EXECUTION_PERIOD_S)

    def _hold(self, now: float) -> None:
        """Stop the arm where it is at ``now`` and hold it there."""
        with self._lock:
            self.motion.move_through([self.motion.position(now)], now)

    def _abort(self, goal_handle, result, code: int, reason: str, now: float):
        self._hold(now)  # a controller holds position on abort
        result.error_code, result.error_string = code, reason
        self.get_logger().warning(f"follow_joint_trajectory: aborted (error code {code}): {reason}")
        goal_handle.abort()
        return result

    # -- publishing -----------------------------------------------------------------------------
    def _link_poses(self, q: np.ndarray) -> dict[str, np.ndarray]:
        poses = {}
        for joint in self.joints:
            for link in (joint.parent, joint.child):
                if link not in poses:
                    poses[link] = self.robot.frame_pose(q, link) if self.robot.model.existFrame(link) else np.eye(4)
        return poses

    def _relative(self, joint: UrdfJoint, poses: dict[str, np.ndarray]) -> np.ndarray:
        return np.linalg.solve(poses[joint.parent], poses[joint.child])

    def _publish_static(self) -> None:
        q = self.robot.reference_q
        poses = self._link_poses(q)
        stamp = self.get_clock().now().to_msg()
        fixed = [_transform(j.parent, j.child, self._relative(j, poses), stamp) for j in self.joints if j.fixed]
        self.tf_static_pub.publish(TFMessage(transforms=fixed))

    def _broadcast_loop(self, period_s: float) -> None:
        """Publish the state every ``period_s`` (a monotonic schedule; ticks missed in a stall are not made up)."""
        due = time.monotonic()
        while not self._stop_broadcast.is_set() and self.context.ok():
            try:
                self._publish()
            except Exception as exc:  # keep broadcasting; say what failed
                if self._stop_broadcast.is_set() or not self.context.ok():
                    return
                self._broadcast_errors += 1
                self.get_logger().error(
                    f"joint_states/tf broadcast failed ({type(exc).__name__}: {exc}); "
                    f"{self._broadcast_errors} failure(s) so far",
                    throttle_duration_sec=5.0,
                )
            due = max(due + period_s, time.monotonic())
            self._stop_broadcast.wait(due - time.monotonic())

    def destroy_node(self) -> None:
        self._stop_broadcast.set()
        self._broadcaster.join(timeout=2.0)
        super().destroy_node()

    def _publish(self) -> None:
        now_msg = self.get_clock().now().to_msg()
        now = now_msg.sec + now_msg.nanosec * 1e-9
        with self._lock:
            q, dq = self.motion.position(now), self.motion.velocity(now)
        for group in (self.arm_joints, self.gripper):
            if not group:
                continue
            index = [self.robot.joint_names.index(n) for n in group]
            joints = JointState()
            joints.header.stamp = now_msg
            joints.name = list(group)
            joints.position = [float(q[i]) for i in index]
            joints.velocity = [float(dq[i]) for i in index]
            self.joint_pub.publish(joints)
        if self._posed_q is None or not np.array_equal(q, self._posed_q):
            # the kinematics only when the arm moved: at rest the same transforms go out, newly stamped
            poses = self._link_poses(q)
            self._moving_tf = [
                _transform(j.parent, j.child, self._relative(j, poses), now_msg) for j in self.joints if not j.fixed
            ]
            self._camera_pose = None
            self._posed_q = q.copy()
        for transform in self._moving_tf:
            transform.header.stamp = now_msg
        self.tf_pub.publish(TFMessage(transforms=self._moving_tf))
        if self.pose_pub.get_subscription_count() == 0:
            return  # nobody listens to the private camera-pose topic (it is TF's pose too)
        if self._camera_pose is None:
            pose = self.robot.camera_pose(q)
            msg = PoseStamped()
            msg.header.frame_id = self.config.world_frame
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in pose[:3, 3])
            o = msg.pose.orientation
            o.x, o.y, o.z, o.w = (float(v) for v in quaternion_from_matrix(pose[:3, :3]))
            self._camera_pose = msg
        self._camera_pose.header.stamp = now_msg
        self.pose_pub.publish(self._camera_pose)


def _desired(times: np.ndarray, positions: np.ndarray, start: np.ndarray, t: float) -> np.ndarray:
    """The setpoint at ``t`` s: linear between the start and the points (as the arm moves)."""
    all_times = np.r_[0.0, times]
    all_points = np.vstack([start, positions])
    return np.array([np.interp(t, all_times, all_points[:, j]) for j in range(all_points.shape[1])])


def main(args: list[str] | None = None) -> int:
    return run_node(ArmSim, args, threads=4)


if __name__ == "__main__":
    raise SystemExit(main())
