"""The movers of ``nbv_planner``'s Explore action, one per ``move_mode``: each takes a planned view
(a ``PlanNextBestView`` response) to the robot and returns the stamp (ns) from which frames are
taken there (:class:`~nbv_prob_cnn.exploration.session.Mover`).

* ``service``: ``/sim_camera/move_to`` (MoveCamera); its answer carries the frame's stamp.
* ``topic``: publish ``/camera/goal_pose`` and wait for the camera to arrive (:class:`CameraPosition`:
  ``camera_frame`` by TF, or ``/camera/pose``).
* ``arm``: the joint goal to ``/arm_sim/move_to_joints`` (MoveToJoints), then wait for
  ``joint_states`` to reach it.
* ``trajectory``: the planned joint path, timed within the limits, to a ``joint_trajectory_controller``'s
  FollowJointTrajectory action, then wait for ``joint_states`` at the goal.

In the arm and trajectory modes a move the robot did not make raises
:class:`~nbv_prob_cnn.exploration.session.MoveError` (the exploration tries another view); a camera
that cannot move raises ValueError or TimeoutError (the exploration ends with the error).
"""

from __future__ import annotations

import threading
from typing import Any, Protocol

import numpy as np
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance
from geometry_msgs.msg import PoseStamped, TransformStamped
from nbv_prob_cnn_msgs.srv import MoveCamera, MoveToJoints, PlanNextBestView
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectoryPoint

from nbv_prob_cnn.arm.arm_session import ArmSession
from nbv_prob_cnn.arm.execution import TrajectoryLimits, controller_joints, timed_joint_path
from nbv_prob_cnn.basics.interrupt import Interrupt, Waitable, WaitInterruptedError
from nbv_prob_cnn.exploration.session import MoveError, PlannedView
from nbv_prob_cnn.perception.messages import stamp_ns
from nbv_prob_cnn.perception.tf_buffer import TransformError
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.action_client import LockedActionClient
from nbv_prob_cnn.ros.conversions import pose_to_arrays
from nbv_prob_cnn.ros.graph import send_goal_with_resend
from nbv_prob_cnn.ros.robot_params import JointStateTracker
from nbv_prob_cnn.ros.runtime import call_service
from nbv_prob_cnn.ros.tf_listener import TfListener

#: A planned view of the Explore action: the planner's response.
PlannedResponse = PlannedView[PlanNextBestView.Response]


class MoverParams(Protocol):
    """The parameters of ``nbv_planner`` the movers read."""

    frame_id: str
    move_timeout_s: float
    arrival_tolerance_m: float
    joint_tolerance: float
    trajectory_action: str
    controller_joints: list
    trajectory_velocity_scale: float
    max_joint_acceleration: float
    max_joint_jerk: float
    trajectory_dt_s: float
    goal_tolerance: float


def duration_msg(seconds: float) -> Duration:
    """``builtin_interfaces/Duration`` of a non-negative number of seconds."""
    nanoseconds = round(seconds * 1e9)
    return Duration(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def wait_future(future: Any, timeout_s: float, what: str, interrupt: Interrupt) -> Any:
    """The result of an rclpy future completed by the executor's other threads.

    Raises:
        MoveError: not done within ``timeout_s``, or it raised.
        WaitInterruptedError: ``interrupt`` was triggered first.
    """
    waitable: Waitable = future
    if not interrupt.wait_future(waitable, timeout_s):
        raise MoveError(f"no {what} within {timeout_s:.0f} s")
    if future.exception() is not None:
        raise MoveError(f"{what} failed: {future.exception()}")
    return future.result()


def run_action_goal(
    node: Node, client: LockedActionClient, goal: Any, action: str, answer_timeout_s: float, result_timeout_s: float,
    interrupt: Interrupt, kind: str, missing: str = "", rejected: str = "",
) -> tuple[Any, int]:  # fmt: skip
    """Send ``goal`` to ``action`` (once its server is up, within ``answer_timeout_s`` but at most
    10 s) and wait for the result: ``(outcome, time sent in ns of node's clock)``. The same goal is
    sent again while no answer comes (a first request can be lost, see graph); an interrupt while the
    result is awaited cancels the goal (the arm stops too; the answer is not awaited). ``kind``
    names the goal in errors (``"trajectory"``); ``missing`` and ``rejected`` add a hint to them.

    Raises:
        MoveError: no server, no answer, the goal rejected, or no result within ``result_timeout_s``.
        WaitInterruptedError: ``interrupt`` was triggered.
    """
    if not interrupt.wait_until(client.server_is_ready, min(answer_timeout_s, 10.0)):
        raise MoveError(f"action {action} is not available{missing}")
    sent = node.get_clock().now().nanoseconds
    try:
        handle = send_goal_with_resend(client, goal, answer_timeout_s, wait=interrupt.wait_until, resend_s=5.0)
    except TimeoutError as exc:
        raise MoveError(f"{action}: the {kind} goal got no answer ({exc})") from exc
    if not handle.accepted:
        raise MoveError(f"{action} rejected the {kind} goal{rejected}")
    try:
        return wait_future(handle.get_result_async(), result_timeout_s, f"{kind} result", interrupt), sent
    except WaitInterruptedError:
        handle.cancel_goal_async()
        raise


class CameraPosition:
    """The camera's newest position: by TF (``camera_frame`` in the requested frame) or from the
    ``/camera/pose`` messages given to :meth:`receive`; :meth:`wait_until` wakes on each message
    (and on :meth:`receive` without one: a timer re-checks TF)."""

    def __init__(self, tf: TfListener | None, camera_frame: str) -> None:
        self._tf, self._camera_frame = tf, camera_frame
        self._condition = threading.Condition()
        self._pose: TransformStamped | None = None

    def receive(self, msg: TransformStamped | None = None) -> None:
        with self._condition:
            if msg is not None:
                self._pose = msg
            self._condition.notify_all()

    def position(self, frame: str) -> tuple[np.ndarray, int] | None:
        """The position in ``frame`` and its stamp (ns); None before there is one."""
        if self._tf is not None:
            try:
                matrix, stamp = self._tf.lookup(frame, self._camera_frame)
            except TransformError:
                return None
            return matrix[:3, 3], stamp
        pose = self._pose
        if pose is None:
            return None
        t = pose.transform.translation
        return np.array([t.x, t.y, t.z]), stamp_ns(pose.header.stamp)

    def wait_until_at(
        self, frame: str, goal: np.ndarray, tolerance_m: float, since_ns: int, timeout_s: float, interrupt: Interrupt
    ) -> int:
        """Wait until a position stamped at or after ``since_ns`` lies within ``tolerance_m`` of
        ``goal``; returns its stamp (ns).

        Raises:
            TimeoutError: not within ``timeout_s``.
            WaitInterruptedError: ``interrupt`` was triggered first.
        """
        reached: list[int] = []

        def arrived() -> bool:
            current = self.position(frame)
            if current is None or current[1] < since_ns or float(np.linalg.norm(current[0] - goal)) > tolerance_m:
                return False
            reached.append(current[1])
            return True

        with self._condition:
            if not interrupt.wait_for(self._condition, arrived, timeout_s):
                raise TimeoutError(f"camera did not report arrival within {timeout_s:.0f} s")
            return reached[-1]


class CameraServiceMover:
    """``move_mode`` service: ``/sim_camera/move_to``; ValueError when it answers a failure."""

    def __init__(self, node: Node, params: MoverParams, callback_group=None) -> None:
        self._node, self._timeout_s = node, params.move_timeout_s
        self._client = node.create_client(MoveCamera, names.MOVE_TO, callback_group=callback_group)

    def move(self, planned: PlannedResponse, interrupt: Interrupt) -> int:
        request = MoveCamera.Request(target=planned.target.best_pose)
        reply = call_service(self._node, self._client, request, self._timeout_s, interrupt)
        if not reply.success:
            raise ValueError(f"camera move failed: {reply.message}")
        return stamp_ns(reply.frame_stamp)


class CameraTopicMover:
    """``move_mode`` topic: publish the goal pose, wait for the camera there (TimeoutError when it
    does not arrive)."""

    def __init__(self, node: Node, params: MoverParams, camera: CameraPosition) -> None:
        self._node, self._params, self._camera = node, params, camera
        self._publisher = node.create_publisher(PoseStamped, names.GOAL_POSE, 10)

    def move(self, planned: PlannedResponse, interrupt: Interrupt) -> int:
        target = planned.target.best_pose
        goal_position, _ = pose_to_arrays(target.pose)
        self._publisher.publish(target)
        sent = self._node.get_clock().now().nanoseconds
        frame, params = target.header.frame_id or self._params.frame_id, self._params
        return self._camera.wait_until_at(
            frame, goal_position, params.arrival_tolerance_m, sent, params.move_timeout_s, interrupt
        )


class JointGoalMover:
    """``move_mode`` arm: the joint goal to ``/arm_sim/move_to_joints``; returns the stamp (ns) of
    the first joint state at the goal (frames stamped at or after it are taken there)."""

    def __init__(self, node: Node, params: MoverParams, joints: JointStateTracker, callback_group=None) -> None:
        self._node, self._params, self._joints = node, params, joints
        self._client = node.create_client(MoveToJoints, names.MOVE_TO_JOINTS, callback_group=callback_group)

    def move(self, planned: PlannedResponse, interrupt: Interrupt) -> int:
        goal, timeout_s = planned.target.joint_goal, self._params.move_timeout_s
        goal_q = np.asarray(goal.position, dtype=np.float64)
        sent = self._node.get_clock().now().nanoseconds
        request = MoveToJoints.Request(name=list(goal.name), position=list(goal.position))
        reply = call_service(self._node, self._client, request, timeout_s, interrupt)
        if not reply.success:
            raise MoveError(f"arm move failed: {reply.message}")
        try:
            return self._joints.wait_until(goal_q, self._params.joint_tolerance, sent, timeout_s + reply.duration_s,
                                           interrupt)  # fmt: skip
        except TimeoutError as exc:
            raise MoveError(str(exc)) from exc


class TrajectoryMover:
    """``move_mode`` trajectory: the last arm plan's joint path (straight, or planned around
    obstacles), timed within the limits, to the FollowJointTrajectory action; then wait for the
    result and for ``joint_states`` at the goal. MoveError when the server is missing, rejects the
    goal, reports a failure or the arm does not arrive."""

    def __init__(
        self, node: Node, params: MoverParams, joints: JointStateTracker, arm: ArmSession, callback_group=None
    ) -> None:
        self._node, self._params, self._joints, self._arm = node, params, joints, arm
        self._client = LockedActionClient(node, FollowJointTrajectory, params.trajectory_action,
                                    callback_group=callback_group)  # fmt: skip
        self._limits = TrajectoryLimits(params.trajectory_velocity_scale, params.max_joint_acceleration,
                                        params.max_joint_jerk, params.trajectory_dt_s)  # fmt: skip

    def move(self, planned: PlannedResponse, interrupt: Interrupt) -> int:
        try:
            return self._execute(planned.target.joint_goal, interrupt)
        except TimeoutError as exc:
            raise MoveError(str(exc)) from exc

    def _goal(self, q_start: np.ndarray, q_goal: np.ndarray, waypoints: np.ndarray | None):
        robot, params = self._arm.robot, self._params
        path = timed_joint_path(robot, q_start, q_goal, self._limits, waypoints)
        try:
            joints = controller_joints(robot, params.controller_joints)
        except ValueError as exc:
            raise MoveError(str(exc)) from exc
        index = [robot.joint_names.index(n) for n in joints]
        request = FollowJointTrajectory.Goal()
        request.trajectory.joint_names = joints
        request.trajectory.points = [
            JointTrajectoryPoint(
                positions=[float(v) for v in path.positions[k, index]],
                velocities=[float(v) for v in path.velocities[k, index]],
                accelerations=[float(v) for v in path.accelerations[k, index]],
                time_from_start=duration_msg(float(t)),
            )
            for k, t in enumerate(path.times)
            if k > 0 or path.times.size == 1
        ]  # fmt: skip
        request.goal_tolerance = [JointTolerance(name=n, position=params.goal_tolerance) for n in joints]
        request.goal_time_tolerance = duration_msg(params.move_timeout_s)
        return request, path.duration

    def _execute(self, goal, interrupt: Interrupt) -> int:
        plan = self._arm.planned_move()
        if plan is None:
            raise MoveError("no planned joint path to execute")
        q_start, view = plan
        q_goal = self._arm.robot.joint_state_configuration(goal.name, goal.position)
        request, duration = self._goal(q_start, q_goal, view.waypoints)
        params, action = self._params, self._params.trajectory_action
        outcome, sent = run_action_goal(self._node, self._client, request, action, params.move_timeout_s,
                                        duration + 2 * params.move_timeout_s, interrupt, "trajectory",
                                        rejected=" (see the controller's log)")  # fmt: skip
        code, text = outcome.result.error_code, outcome.result.error_string
        if outcome.status != GoalStatus.STATUS_SUCCEEDED or code != FollowJointTrajectory.Result.SUCCESSFUL:
            raise MoveError(f"{action} failed: error code {code} {text!r} (status {outcome.status})")
        tolerance = max(params.joint_tolerance, params.goal_tolerance)
        return self._joints.wait_until(q_goal, tolerance, sent, params.move_timeout_s, interrupt)
