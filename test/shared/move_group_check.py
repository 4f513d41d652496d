"""A MoveGroup action server for the tests (not product code): it stands where MoveIt 2's
``move_group`` serves ``/move_action``, checks each goal as ``move_group`` does before it plans, and
executes the accepted ones through ``arm_sim``'s FollowJointTrajectory controller, as MoveIt's
trajectory execution manager does.

The checks, each answered with the ``MoveItErrorCodes`` value MoveIt gives:

* ``request.group_name`` is the group (``INVALID_GROUP_NAME``);
* one goal ``Constraints`` at least (``INVALID_GOAL_CONSTRAINTS``), each of them a pose goal (one
  position and one orientation constraint of the same link) or a joint goal (a joint constraint for
  every joint of the group, no others), with weights > 0 (``INVALID_GOAL_CONSTRAINTS``);
* every link is a link of the robot (``INVALID_LINK_NAME``), every frame the planning frame
  (``FRAME_TRANSFORM_FAILURE``: this server knows no TF);
* a position constraint's region is one ``SolidPrimitive`` sphere with its pose, of the expected
  radius; orientation tolerances and joint tolerances as expected, a unit quaternion
  (``INVALID_GOAL_CONSTRAINTS``);
* the start state is the current state (``start_state.is_diff``), planning time and scaling within
  MoveIt's ranges (``INVALID_MOTION_PLAN``).

Planning: a joint goal is the goal; a pose goal is solved by our IK from the current configuration
(``NO_IK_SOLUTION`` when it fails, and the solution is checked against the constraints). The path is
the straight joint path timed within ``velocity_scaling`` × the URDF limits. ``answers`` makes the
first goals fail with given codes (a planner that finds no path, a goal in collision) after the
checks.
"""

from __future__ import annotations

import threading
import time

import numpy as np
from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory
from moveit_msgs.action import MoveGroup
from moveit_msgs.msg import MoveItErrorCodes
from rclpy.action import ActionServer
from rclpy.callback_groups import ReentrantCallbackGroup
from sensor_msgs.msg import JointState
from shape_msgs.msg import SolidPrimitive
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from nbv_prob_cnn.arm.execution import TrajectoryLimits, timed_joint_path
from nbv_prob_cnn.arm.ik import solve_camera_pose
from nbv_prob_cnn.arm.kinematics import CameraChain
from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.basics.camera import matrix_from_quaternion
from nbv_prob_cnn.ros.action_client import LockedActionClient
from nbv_prob_cnn.ros.graph import send_goal_with_resend
from nbv_prob_cnn.ros.movers import duration_msg

E = MoveItErrorCodes


class GoalRefusedError(Exception):
    """A goal check failed: the MoveIt error code and why."""

    def __init__(self, code: int, why: str) -> None:
        super().__init__(why)
        self.code = code


class MoveGroupCheck:
    """The test's ``move_group`` (see the module docstring). ``goals`` records every goal received,
    ``answered`` every error code sent back."""

    def __init__(
        self,
        node,
        robot: RobotModel,
        *,
        group: str = "panda_arm",
        planning_frame: str = "world",
        position_tolerance_m: float = 0.01,
        orientation_tolerance_rad: float = 0.05,
        joint_tolerance: float = 0.01,
        controller: str = "/arm_controller/follow_joint_trajectory",
        answers: tuple[int, ...] = (),
        action: str = "/move_action",
    ) -> None:
        self.node, self.robot, self.group, self.frame = node, robot, group, planning_frame
        self.tolerances = (position_tolerance_m, orientation_tolerance_rad, joint_tolerance)
        self.chain = CameraChain(robot)
        self.group_joints = [robot.joint_names[i] for i in robot.chain]
        self.links = {frame.name for frame in robot.model.frames}
        self.answers = list(answers)
        self.goals: list[MoveGroup.Goal] = []
        self.answered: list[int] = []
        self._lock = threading.Lock()
        self._q: np.ndarray | None = None  # the current configuration (joint_states, merged)
        group_cb = ReentrantCallbackGroup()
        node.create_subscription(JointState, "/joint_states", self._on_joints, 50, callback_group=group_cb)
        self._controller = LockedActionClient(node, FollowJointTrajectory, controller, callback_group=group_cb)
        self._server = ActionServer(node, MoveGroup, action, execute_callback=self._execute, callback_group=group_cb)

    def _on_joints(self, msg: JointState) -> None:
        with self._lock:
            q = np.array(self.robot.reference_q if self._q is None else self._q)
            for name, value in zip(msg.name, msg.position, strict=True):
                if name in self.robot.joint_names:
                    q[self.robot.joint_names.index(name)] = value
            self._q = q

    def current(self) -> np.ndarray:
        deadline = time.monotonic() + 30.0
        while self._q is None and time.monotonic() < deadline:
            time.sleep(0.05)
        if self._q is None:
            raise GoalRefusedError(E.ROBOT_STATE_STALE, "no joint_states")
        with self._lock:
            return self._q.copy()

    # -- the checks -------------------------------------------------------------------------------
    def check(self, goal: MoveGroup.Goal) -> list:
        """The goal's constraints as ``[("joints", q_goal_of_group) | ("pose", link, 4x4)]``."""
        request = goal.request
        if request.group_name != self.group:
            raise GoalRefusedError(E.INVALID_GROUP_NAME, f"no group {request.group_name!r}")
        if not request.start_state.is_diff:
            raise GoalRefusedError(E.INVALID_ROBOT_STATE, "the start state must be the current one (is_diff)")
        if not request.allowed_planning_time > 0 or not request.num_planning_attempts >= 1:
            raise GoalRefusedError(E.INVALID_MOTION_PLAN, "planning time / attempts")
        for scale in (request.max_velocity_scaling_factor, request.max_acceleration_scaling_factor):
            if not 0 < scale <= 1:
                raise GoalRefusedError(E.INVALID_MOTION_PLAN, f"scaling factor {scale} outside (0, 1]")
        if not request.goal_constraints:
            raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, "no goal constraints")
        return [self._constraints(c) for c in request.goal_constraints]

    def _constraints(self, c):
        position_tol, angle_tol, joint_tol = self.tolerances
        if c.visibility_constraints:
            raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, "visibility constraints are not goal constraints here")
        if c.joint_constraints:
            if c.position_constraints or c.orientation_constraints:
                raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, "joint and pose constraints mixed")
            names = [j.joint_name for j in c.joint_constraints]
            if sorted(names) != sorted(self.group_joints):
                raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, f"joints {names}, group {self.group_joints}")
            for j in c.joint_constraints:
                if j.weight <= 0 or not np.isclose([j.tolerance_above, j.tolerance_below], joint_tol).all():
                    raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, f"joint {j.joint_name}: weight / tolerances")
            return ("joints", {j.joint_name: j.position for j in c.joint_constraints})
        if len(c.position_constraints) != 1 or len(c.orientation_constraints) != 1:
            raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, "a pose goal: one position + one orientation constraint")
        p, o = c.position_constraints[0], c.orientation_constraints[0]
        for link in (p.link_name, o.link_name):
            if link not in self.links:
                raise GoalRefusedError(E.INVALID_LINK_NAME, f"no link {link!r}")
        if p.link_name != o.link_name:
            raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, "position and orientation of different links")
        for frame in (p.header.frame_id, o.header.frame_id):
            if frame != self.frame:
                raise GoalRefusedError(E.FRAME_TRANSFORM_FAILURE, f"frame {frame!r} is not {self.frame!r}")
        region = p.constraint_region
        if (
            len(region.primitives) != 1 or len(region.primitive_poses) != 1 or region.meshes
            or region.primitives[0].type != SolidPrimitive.SPHERE
            or not np.isclose(list(region.primitives[0].dimensions), [position_tol]).all()
            or p.weight <= 0 or o.weight <= 0
        ):  # fmt: skip
            raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, "the position region is not one sphere of the tolerance")
        tolerances = [o.absolute_x_axis_tolerance, o.absolute_y_axis_tolerance, o.absolute_z_axis_tolerance]
        q = o.orientation
        quaternion = np.array([q.x, q.y, q.z, q.w])
        if not np.isclose(tolerances, angle_tol).all() or abs(np.linalg.norm(quaternion) - 1) > 1e-6:
            raise GoalRefusedError(E.INVALID_GOAL_CONSTRAINTS, "orientation tolerances / quaternion")
        centre = region.primitive_poses[0].position
        pose = np.eye(4)
        pose[:3, :3] = matrix_from_quaternion(quaternion)
        pose[:3, 3] = [centre.x + p.target_point_offset.x, centre.y + p.target_point_offset.y,
                       centre.z + p.target_point_offset.z]  # fmt: skip
        return ("pose", p.link_name, pose)

    # -- planning and execution -----------------------------------------------------------------
    def _goal_configuration(self, target, current: np.ndarray) -> np.ndarray:
        if target[0] == "joints":
            return self.robot.configuration(target[1], base=current)
        _, link, pose = target
        if link != self.robot.model.frames[self.robot.camera_frame].name:
            raise GoalRefusedError(E.NO_IK_SOLUTION, f"this server solves the IK of the camera link only, not {link!r}")
        solved = solve_camera_pose(self.chain, pose, current, np.random.default_rng(0))
        if solved.q is None:
            raise GoalRefusedError(E.NO_IK_SOLUTION, "no IK solution")
        reached = self.robot.camera_pose(solved.q)
        position_tol, angle_tol, _ = self.tolerances
        angle = np.arccos(np.clip((np.trace(reached[:3, :3].T @ pose[:3, :3]) - 1) / 2, -1, 1))
        if np.linalg.norm(reached[:3, 3] - pose[:3, 3]) > position_tol or angle > angle_tol:
            raise GoalRefusedError(E.GOAL_CONSTRAINTS_VIOLATED, "the IK solution violates the goal constraints")
        return solved.q

    def _execute(self, handle) -> MoveGroup.Result:
        goal: MoveGroup.Goal = handle.request
        result = MoveGroup.Result()
        with self._lock:
            self.goals.append(goal)
            injected = self.answers.pop(0) if self.answers else None
        start = time.perf_counter()
        try:
            targets = self.check(goal)
            if injected is not None:
                raise GoalRefusedError(injected, "injected by the test")
            current = self.current()
            q_goal = self._goal_configuration(targets[0], current)
            trajectory = self._trajectory(goal, current, q_goal)
            result.planning_time = time.perf_counter() - start
            result.planned_trajectory.joint_trajectory = trajectory
            self._run(trajectory)
            result.executed_trajectory.joint_trajectory = trajectory
            result.error_code.val = E.SUCCESS
        except GoalRefusedError as refused:
            result.error_code.val, result.error_code.message = refused.code, str(refused)
            result.error_code.source = "move_group_check"
        with self._lock:
            self.answered.append(int(result.error_code.val))
        if result.error_code.val == E.SUCCESS:
            handle.succeed()
        else:
            handle.abort()  # move_group aborts a goal that failed, the error code in the result
        return result

    def _trajectory(self, goal: MoveGroup.Goal, current: np.ndarray, q_goal: np.ndarray) -> JointTrajectory:
        request = goal.request
        limits = TrajectoryLimits(request.max_velocity_scaling_factor, 3.0 * request.max_acceleration_scaling_factor,
                                  30.0, 0.05)  # fmt: skip
        path = timed_joint_path(self.robot, current, q_goal, limits)
        index = [self.robot.joint_names.index(n) for n in self.group_joints]
        trajectory = JointTrajectory(joint_names=self.group_joints)
        trajectory.points = [
            JointTrajectoryPoint(positions=[float(v) for v in path.positions[k, index]],
                                 velocities=[float(v) for v in path.velocities[k, index]],
                                 time_from_start=duration_msg(float(t)))
            for k, t in enumerate(path.times) if k > 0 or path.times.size == 1
        ]  # fmt: skip
        return trajectory

    def _run(self, trajectory: JointTrajectory) -> None:
        """Execute through the controller (MoveIt's trajectory execution); CONTROL_FAILED when it fails."""
        if not self._controller.wait_for_server(timeout_sec=60.0):
            raise GoalRefusedError(E.CONTROL_FAILED, "no controller")
        goal = FollowJointTrajectory.Goal(trajectory=trajectory)
        handle = send_goal_with_resend(self._controller, goal, 60.0, resend_s=5.0)
        if not handle.accepted:
            raise GoalRefusedError(E.CONTROL_FAILED, "the controller rejected the trajectory")
        future = handle.get_result_async()
        deadline = time.monotonic() + 120.0
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.02)
        outcome = future.result() if future.done() else None
        if outcome is None or outcome.status != GoalStatus.STATUS_SUCCEEDED or outcome.result.error_code != 0:
            raise GoalRefusedError(E.CONTROL_FAILED, f"the controller failed: {outcome}")
