"""Node ``nbv_planner``: plans next best views on the integrator's grid.

* ``/nbv/plan`` (PlanNextBestView): completion (``/nbv/complete``) and best-view search
  (``/nbv/rank_views``) through the servers, or everything in this process with
  ``in_process:=true``. Publishes ``/nbv/next_best_view`` and ``/nbv/markers``.
* ``/nbv/explore`` (Explore action): plan, move the camera (``/sim_camera/move_to``, or publish
  ``/camera/goal_pose`` and wait for the camera to arrive there (``camera_frame`` in the grid frame
  by TF, or ``/camera/pose`` with ``pose_source:=topic``), or with ``move_mode:=arm``
  send the joint goal to ``/arm_sim/move_to_joints`` and wait for ``/joint_states`` to reach it,
  or with ``move_mode:=trajectory`` send the joint path (straight, or planned around obstacles by
  OMPL when the straight one collides, ``arm_path_timeout_s``), timed within the velocity,
  acceleration and jerk limits (:func:`~nbv_prob_cnn.arm.trajectory.time_parameterise_path`), to a
  ``joint_trajectory_controller``'s ``control_msgs/FollowJointTrajectory`` action
  (``trajectory_action``, default ``/arm_controller/follow_joint_trajectory``)),
  wait for a grid that includes a frame from the new pose, repeat until a stop condition.
  A move that is rejected or fails (arm / trajectory modes) rules that view out and the next
  feasible ranked view is tried (at most ``max_failed_executions`` in a row); each failure is
  reported in the feedback (``executed`` false, ``execution_error``) and never aborts the goal.
  A view that changed fewer than ``guard_min_cells`` grid cells rules its pose out for the rest
  of the exploration (the view guard, :mod:`~nbv_prob_cnn.exploration.view_guard`; feedback
  ``ruled_out_views``).

Every plan keeps the camera inside the workspace: the ``workspace_min`` / ``workspace_max`` box
and the ``min_camera_height_m`` / ``max_camera_height_m`` heights (grid frame), intersected with
the request's box (``PlanNextBestView`` ``use_workspace``, or the same fields of an ``Explore``
goal), in every ``move_mode``.

With ``use_arm:=true`` (robot description parameters of :class:`RobotParams`) a plan is the best
view the arm reaches collision-free from the configuration of the latest ``/joint_states``
(:class:`~nbv_prob_cnn.arm.selection.ArmViewSelector`, as ``nbv study arm_compare``: views ranked by
gain, capability map, IK and its alternatives, self/grid collision and the straight joint path,
utility ``gain − motion_weight · path length``, a near-camera fallback); the response carries its
joint goal. The planner's grid (not the integrator's) counts as free the cells the arm's bodies
filled at the configurations seen on ``/joint_states`` and along the moves the exploration
commanded (``arm_carve_swept``); a view the exploration moved to is never planned again.
"""

from __future__ import annotations

import array
import threading
import time
from dataclasses import dataclass

import numpy as np
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Point, PoseStamped, TransformStamped
from nbv_prob_cnn_msgs.action import Explore
from nbv_prob_cnn_msgs.msg import ViewScore, VoxelGrid
from nbv_prob_cnn_msgs.srv import CompleteGrid, MoveCamera, MoveToJoints, PlanNextBestView, RankViews
from rclpy.action import ActionClient, ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectoryPoint
from visualization_msgs.msg import MarkerArray

from nbv_prob_cnn.arm.feasibility import ArmView, FeasibilityReport, reached_quaternion, takes_view_mask
from nbv_prob_cnn.arm.path_planning import PathPlannerSettings
from nbv_prob_cnn.arm.selection import ArmViewSelector
from nbv_prob_cnn.arm.swept import SweptVolume
from nbv_prob_cnn.arm.trajectory import TimedPath, time_parameterise_path
from nbv_prob_cnn.arm.views import ArmPlanningSetup
from nbv_prob_cnn.basics.camera import DATASETS
from nbv_prob_cnn.basics.grid import unknown_fraction_all
from nbv_prob_cnn.basics.interrupt import Interrupt, WaitInterruptedError
from nbv_prob_cnn.basics.modes import BACKEND_NAMES, MOVE_MODES, Backend, MoveMode
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.gain.variant import GAIN_VARIANTS
from nbv_prob_cnn.perception.messages import stamp_ns
from nbv_prob_cnn.perception.tf_buffer import TransformError
from nbv_prob_cnn.planners import check_ros_method, make_planner, ros_method
from nbv_prob_cnn.planners.ranked_views import ranked_from_arrays, view_mask_to_bytes
from nbv_prob_cnn.planners.requests import choice_from_pose, flat_cells, origin_filter, planning_context, view_pose
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.camera_sensor import CameraInfoSensor, SensorParams
from nbv_prob_cnn.ros.conversions import (
    arrays_to_pose_stamped,
    geometry_of,
    grid_to_msg,
    msg_to_grid,
    msg_to_probability,
    pose_to_arrays,
    probability_to_msg,
)
from nbv_prob_cnn.ros.grid_holder import LatestGrid
from nbv_prob_cnn.ros.joint_state_intake import JointStateIntake
from nbv_prob_cnn.ros.markers import planning_markers
from nbv_prob_cnn.ros.parameters import declare_config, param, positive_seconds
from nbv_prob_cnn.ros.readiness import READY, SETTING_UP, ReadinessPublisher
from nbv_prob_cnn.ros.robot_params import ArmViewParams, joint_state_msg
from nbv_prob_cnn.ros.runtime import call_service, run_node, shutdown_interrupt
from nbv_prob_cnn.ros.stream_node import StreamNode
from nbv_prob_cnn.ros.tf_listener import POSE_SOURCES, TfListener

#: Joint-space step (rad) between the configurations whose bodies are carved free (joint_states
#: samples kept, samples of a commanded path), as ``SweptVolume``'s default.
SWEPT_STEP = 0.02
#: Planning's message when every candidate view has zero gain (a normal end of an exploration).
NO_POSITIVE_GAIN = "no view with positive gain"
#: Planning's message (prefix) when ``use_arm`` finds no view the arm can take (also an end of an exploration).
NO_REACHABLE_VIEW = "no view the arm reaches collision-free"
#: Box bound standing for "no limit" on an axis.
UNBOUNDED = 1e9
#: Reason of an exploration's interrupt when its goal is canceled.
GOAL_CANCELED = "goal canceled"
#: An accepted goal that never reached execution (its acceptance failed in rclpy) frees the
#: exploration slot after this long.
GOAL_CLAIM_S = 10.0


class ExecutionError(RuntimeError):
    """The robot did not take the planned view (rejected goal, failed execution, an arm that
    did not arrive): the exploration rules the view out and tries the next one."""


class RecordingPlanner:
    """A planner whose ``rank`` also applies the request's origin filter (after the arm's
    capability filter, kept as ``arm_filter`` for the ranking server) and keeps the ranked list
    (markers, ``ranked`` of the response)."""

    def __init__(self, planner, request_filter, arm_limit=None) -> None:
        self.planner, self.request_filter, self.arm_limit = planner, request_filter, arm_limit
        self.ranked, self.arm_filter, self.view_mask = [], None, None
        self.seconds = 0.0  # the last rank's time (CNN included)
        self.takes_view_mask = takes_view_mask(planner)  # passed on to the planner (plan_with_arm)

    def rank(self, state, context, top_k=1, origin_filter=None, view_mask=None):
        keep, capability, limit = self.request_filter, origin_filter, self.arm_limit

        def arm_filter(origins):
            return capability(origins if limit is None else limit(origins))

        def both(origins):
            return keep(origins if capability is None else arm_filter(origins))

        self.arm_filter = None if capability is None else arm_filter
        self.view_mask = view_mask  # a remote ranking gets it as allowed_views
        start = time.perf_counter()
        if view_mask is None:
            self.ranked = self.planner.rank(state, context, top_k, both)
        else:
            self.ranked = self.planner.rank(state, context, top_k, both, view_mask=view_mask)
        self.seconds = time.perf_counter() - start
        return self.ranked


@dataclass
class PlannerConfig(SensorParams, ArmViewParams):
    """Parameters of ``nbv_planner`` (``method`` and ``service_timeout_s`` may change at run time):
    the robot description and ``use_arm`` (:class:`ArmViewParams`), the planning frustum
    (:class:`SensorParams`: CameraInfo + range), then these."""

    pose_source: str = param(
        "tf", "camera pose (move_mode topic: arrival): tf (camera_frame in the grid frame, newest) or topic "
        "(/camera/pose)", choices=POSE_SOURCES,
    )  # fmt: skip
    dataset: str = param("3dt", "sensor/ray defaults and CNN weights", choices=tuple(sorted(DATASETS)))
    method: str = param("cnn_prob", "method when a request names none", dynamic=True, check=check_ros_method)
    in_process: bool = param(False, "complete and ray-cast here instead of via the servers")
    backend: Backend = param("auto", "ray-casting backend (in-process mode)", choices=BACKEND_NAMES)
    n_rays: int = param(0, "ray sub-cells per side (0 = default)", min_value=0, max_value=64)
    gain_variant: str = param(
        "paper", "gain in-process ('paper' or 'original', docs/original_code.md; else gain_server's)",
        choices=GAIN_VARIANTS,
    )  # fmt: skip
    frame_id: str = param("world", "frame of grids that carry none")
    service_timeout_s: float = param(
        60.0, "completion/ranking wait", min_value=0.1, max_value=600.0, dynamic=True, check=positive_seconds
    )
    move_mode: MoveMode = param(
        "service",
        "'service' (sim_camera/move_to), 'topic' (goal pose), 'arm' (arm_sim/move_to_joints) or 'trajectory' "
        "(FollowJointTrajectory); arm and trajectory need use_arm",
        choices=MOVE_MODES,
    )  # fmt: skip
    workspace_min: list = param([], "camera workspace box corner [x, y, z] (grid frame, m; [] = no box)")
    workspace_max: list = param([], "camera workspace box corner [x, y, z] (grid frame, m; [] = no box)")
    min_camera_height_m: float = param(0.0, "lowest camera position z (grid frame, m; 0 = no limit)",
                                       min_value=-100.0, max_value=100.0)  # fmt: skip
    max_camera_height_m: float = param(0.0, "highest camera position z (grid frame, m; 0 = no limit)",
                                       min_value=-100.0, max_value=100.0)  # fmt: skip
    trajectory_action: str = param(
        "/arm_controller/follow_joint_trajectory", "move_mode trajectory: the controller's FollowJointTrajectory action"
    )
    controller_joints: list = param([""], "move_mode trajectory: joints of the controller (['']: the camera chain's)")
    trajectory_velocity_scale: float = param(0.5, "move_mode trajectory: fraction of the URDF velocity limits",
                                             min_value=0.01, max_value=1.0)  # fmt: skip
    max_joint_acceleration: float = param(1.5, "move_mode trajectory: joint acceleration limit (rad/s² or m/s²)",
                                          min_value=1e-3, max_value=1000.0)  # fmt: skip
    max_joint_jerk: float = param(15.0, "move_mode trajectory: joint jerk limit (rad/s³ or m/s³)", min_value=1e-3,
                                  max_value=100000.0)  # fmt: skip
    trajectory_dt_s: float = param(0.05, "move_mode trajectory: time between trajectory points (s)", min_value=0.001,
                                   max_value=10.0)  # fmt: skip
    arm_path_timeout_s: float = param(
        1.0, "move_mode trajectory: when the straight joint path to a view collides, plan one (OMPL RRTConnect, "
        "simplified, checked every 0.05 rad) within this time (s); 0 = straight paths only, as in the other move modes",
        min_value=0.0, max_value=60.0,
    )  # fmt: skip
    goal_tolerance: float = param(0.01, "move_mode trajectory: goal position tolerance sent with the goal (rad or m)",
                                  min_value=0.0, max_value=10.0)  # fmt: skip
    guard_min_cells: int = param(
        -1, "Explore: a pose whose view changed fewer grid cells is never planned again (-1: 5e-5 of the grid's "
        "cells, 0: off)", min_value=-1, max_value=1_000_000_000,
    )  # fmt: skip
    max_failed_executions: int = param(
        5, "arm / trajectory modes: views in a row whose move failed before the exploration stops", min_value=1,
        max_value=1000,
    )  # fmt: skip
    move_timeout_s: float = param(30.0, "wait for the camera to arrive", min_value=0.1, max_value=600.0)
    grid_timeout_s: float = param(30.0, "wait for the grid with the new frame", min_value=0.1, max_value=600.0)
    arrival_tolerance_m: float = param(0.01, "topic mode: position tolerance", min_value=0.0, max_value=1.0)
    markers_top_k: int = param(20, "candidate views shown as markers", min_value=1, max_value=1000)
    motion_weight: float = param(0.0, "use_arm: λ of the utility gain − λ·joint path length", min_value=0.0,
                                 max_value=1000.0)  # fmt: skip
    arm_top_k: int = param(1000, "use_arm: views ranked by gain before the arm's check", min_value=1, max_value=100000)
    arm_max_checks: int = param(30, "use_arm: exact IK + collision checks per plan (0 = all)", min_value=0,
                                max_value=100000)  # fmt: skip
    capability_stride: int = param(8, "use_arm: capability-map lattice stride in cells (0 = no map)", min_value=0,
                                   max_value=64)  # fmt: skip
    arm_min_view_height_m: float = param(
        0.0, "use_arm: only views with the camera at least this high (grid frame z, m; 0 = no limit)", min_value=0.0,
        max_value=100.0,
    )  # fmt: skip
    arm_ik_alternatives: int = param(4, "use_arm: other IK solutions tried when the first collides", min_value=0,
                                     max_value=64)  # fmt: skip
    arm_strict_capability: bool = param(True, "use_arm: capability lookup ANDs the lattice nodes around a cell")
    arm_roll_symmetric: bool = param(
        True, "use_arm: a view turned 180 deg about the optical axis counts as the view (same frustum, same gain): "
        "IK takes whichever is nearer (the image may come upside down; best_pose says which)",
    )  # fmt: skip
    arm_fallback_radius_m: float = param(
        0.25, "use_arm: no ranked view feasible: rank again within this distance (m) of the camera (0 = off)",
        min_value=0.0, max_value=10.0,
    )  # fmt: skip
    arm_carve_swept: bool = param(True, "use_arm: cells the arm has filled (joint_states, moves) count as free")
    joint_tolerance: float = param(1e-3, "move_mode arm: joint arrival tolerance (rad or m)", min_value=1e-6,
                                   max_value=1.0)  # fmt: skip


class NbvPlanner(Node):
    """Plans views on the latest grid and runs explorations."""

    def __init__(self) -> None:
        super().__init__("nbv_planner")
        self.config = declare_config(self, PlannerConfig)  # also sets self.<name> for each parameter
        self._rng = np.random.default_rng()
        self._camera_lock = threading.Condition()
        self._camera_pose: TransformStamped | None = None
        self._explore_lock = threading.Lock()  # guards the four fields below
        self._active_goal = None  # the running exploration's goal handle
        self._canceled_before_start = None  # an accepted goal whose cancel came before its execution
        self._goal_accepted_at: float | None = None  # a goal accepted, not yet executing (monotonic s)
        self._goal_interrupt: Interrupt | None = None  # the running exploration's (cancel and shutdown)
        self._shutdown = shutdown_interrupt(self)  # triggered by run_node when the node stops
        if self.move_mode in ("arm", "trajectory") and not self.use_arm:
            raise ValueError(
                f"move_mode {self.move_mode!r} needs use_arm:=true (the joint goal comes from planning with the arm)"
            )
        self._workspace = workspace_box(self.workspace_min, self.workspace_max)  # raises on bad values
        self._arm: ArmPlanningSetup | None = None
        self._joints: JointStateIntake | None = None
        self._arm_lock = threading.Lock()  # guards the fields below (arm planning runs one at a time)
        self._selectors: dict[tuple, tuple[ArmViewSelector, list]] = {}  # per grid geometry: selector, fed count
        self._seen_lock = threading.Lock()  # guards _seen_q (not _arm_lock: a plan holds that for long)
        self._seen_q: list[np.ndarray] = []  # configurations seen on joint_states, >= one swept step apart
        self._preparing: set[tuple] = set()  # grid geometries whose arm set-up started (guarded by _seen_lock)
        self._last_arm_plan: tuple[ArmViewSelector, np.ndarray, ArmView] | None = None
        self._view_guard: ViewGuard | None = None  # of the running exploration (guard_min_cells)
        self._last_choice = None  # the last plan's view (cell, orientation), for the view guard
        group = ReentrantCallbackGroup()
        if self.use_arm:
            cfg = self.config
            self._arm = ArmPlanningSetup(
                cfg.robot_config(self), cfg.motion_weight, cfg.free_above(), cfg.arm_max_checks, cfg.capability_stride,
                ik_alternatives=cfg.arm_ik_alternatives, strict_capability=cfg.arm_strict_capability,
                path_planning=PathPlannerSettings(timeout_s=cfg.arm_path_timeout_s)
                if self.move_mode == "trajectory" and cfg.arm_path_timeout_s > 0 else None,
                roll_symmetric=cfg.arm_roll_symmetric,
            )  # fmt: skip
        # joint_states and /tf come at the robot's rate: on a side node with its own thread (stream_node)
        self.server_times: dict[str, float] = {}  # the servers' own times on the last plan's requests (log)
        self._streams = StreamNode(self) if self.use_arm or self.pose_source == "tf" else None
        if self._arm is not None and self._streams is not None:
            on_configuration = self._saw_configuration if self.arm_carve_swept else None
            self._joints = JointStateIntake(self._arm.robot, self, self._streams.node, on_configuration)
        self._grid = LatestGrid(self, callback_group=group, on_grid=self._prepare_arm if self._arm else None)
        self._tf = TfListener(self._streams.node) if self.pose_source == "tf" else None
        if self._tf is None:
            self.create_subscription(TransformStamped, names.CAMERA_POSE, self._on_camera_pose, 10,
                                     callback_group=group)  # fmt: skip
        elif self.move_mode not in ("arm", "trajectory"):  # the camera's arrival wait re-checks TF as
            self.create_timer(0.02, self._on_camera_pose, callback_group=group)  # /camera/pose would wake it
        self._sensor = CameraInfoSensor(self, self.config, self.dataset, callback_group=group)
        self._nbv_pub = self.create_publisher(PoseStamped, names.NEXT_BEST_VIEW, 10)
        self._marker_pub = self.create_publisher(MarkerArray, names.MARKERS, 10)
        self._complete_client = self.create_client(CompleteGrid, names.COMPLETE, callback_group=group)
        self._rank_client = self.create_client(RankViews, names.RANK_VIEWS, callback_group=group)
        # only the move interface of move_mode joins the graph (with a real robot, nothing of ours but it)
        self._goal_pub = self.create_publisher(PoseStamped, names.GOAL_POSE, 10) if self.move_mode == "topic" else None
        self._move_client = (
            self.create_client(MoveCamera, names.MOVE_TO, callback_group=group) if self.move_mode == "service" else None
        )
        self._joints_client = (
            self.create_client(MoveToJoints, names.MOVE_TO_JOINTS, callback_group=group)
            if self.move_mode == "arm"
            else None
        )
        self._trajectory_client = (
            ActionClient(self, FollowJointTrajectory, self.trajectory_action, callback_group=group)
            if self.move_mode == "trajectory"
            else None
        )
        self._readiness = ReadinessPublisher(self, ready=not self.use_arm, callback_group=group)
        self.create_service(PlanNextBestView, names.PLAN, self._plan_service, callback_group=group)
        self._action = ActionServer(
            self, Explore, names.EXPLORE, execute_callback=self._explore,
            goal_callback=self._check_goal, cancel_callback=self._cancel_goal, callback_group=group,
        )  # fmt: skip
        mode = "in-process" if self.in_process else "via /nbv/complete and /nbv/rank_views"
        mode += f", arm {self._arm.robot.joint_names} (λ = {self.motion_weight:g})" if self._arm else ""
        self.get_logger().info(f"nbv_planner ready: dataset {self.dataset}, method {self.method}, {mode}")

    # -- inputs -------------------------------------------------------------------------------
    def _prepare_arm(self, msg: VoxelGrid) -> None:
        """use_arm: on the first grid of a geometry, load (or build) its capability map and
        collision model in a background thread, so the first plan does not wait for them (a plan
        that comes earlier waits for the thread under ``_arm_lock``)."""
        try:
            geometry = geometry_of(msg)
        except ValueError:
            return  # the plan reports the bad grid
        key = (tuple(geometry.origin), float(geometry.resolution), tuple(geometry.shape))
        with self._seen_lock:
            if key in self._preparing or geometry.dims != 3:
                return
            self._preparing.add(key)

        def prepare() -> None:
            start = time.perf_counter()
            try:
                with self._arm_lock:
                    self._selector(geometry)
            except ValueError as exc:  # e.g. an arm that reaches nothing of this grid: the plan says so
                self.get_logger().warning(f"arm set-up for the grid failed: {exc}")
                self._readiness.set(DiagnosticStatus.ERROR, f"arm set-up for the grid failed: {exc}")
                return
            self.get_logger().info(f"arm set-up for the grid (capability map, collision model): "
                                   f"{time.perf_counter() - start:.1f} s")  # fmt: skip
            self._readiness.set(DiagnosticStatus.OK, READY)

        self._readiness.set(DiagnosticStatus.WARN, SETTING_UP)
        threading.Thread(target=prepare, name="arm_setup", daemon=True).start()

    def _on_camera_pose(self, msg: TransformStamped | None = None) -> None:
        with self._camera_lock:
            if msg is not None:
                self._camera_pose = msg
            self._camera_lock.notify_all()

    def _camera_position(self, frame: str) -> tuple[np.ndarray, int] | None:
        """The camera's newest position in ``frame`` and its stamp (ns): by TF (``camera_frame``)
        or from /camera/pose; None before there is one."""
        if self._tf is not None:
            try:
                matrix, stamp = self._tf.lookup(frame, self.config.camera_frame)
            except TransformError:
                return None
            return matrix[:3, 3], stamp
        pose = self._camera_pose
        if pose is None:
            return None
        t = pose.transform.translation
        return np.array([t.x, t.y, t.z]), stamp_ns(pose.header.stamp)

    def _saw_configuration(self, q: np.ndarray) -> None:
        """arm_carve_swept: keep a configuration seen on joint_states (one swept step from the last kept)."""
        with self._seen_lock:
            if not self._seen_q or np.abs(q - self._seen_q[-1]).max() >= SWEPT_STEP:
                self._seen_q.append(q)

    def _selector(self, geometry) -> ArmViewSelector:
        """The arm's view selector of this grid geometry, its swept volume brought up to date
        with the configurations seen on joint_states (call with ``_arm_lock`` held)."""
        key = (tuple(geometry.origin), float(geometry.resolution), tuple(geometry.shape))
        if key not in self._selectors:
            arm = self._arm.feasibility(geometry)
            swept = SweptVolume(arm.checker, geometry, SWEPT_STEP) if self.arm_carve_swept else None
            self._selectors[key] = (ArmViewSelector(arm, geometry, swept, self.arm_fallback_radius_m), [0])
        selector, fed = self._selectors[key]
        self._sweep_seen(selector, fed)
        return selector

    def _sweep_seen(self, selector: ArmViewSelector, fed: list[int]) -> None:
        """Add the configurations seen on joint_states since the last call to the selector's swept
        volume (``fed[0]``: how many it has had; call with ``_arm_lock`` held)."""
        if selector.swept is None:
            return
        with self._seen_lock:
            seen = self._seen_q[fed[0] :]
        for q in seen:
            selector.swept.add_configuration(q)
        fed[0] += len(seen)

    def _took_planned_view(self) -> None:
        """The exploration moved the camera to the last plan's view: it is taken; when the arm
        moved there (``move_mode`` arm or trajectory), its joint path is swept too, and so are the
        joint states seen during the move."""
        with self._arm_lock:
            if self._last_arm_plan is not None:
                selector, q_start, view = self._last_arm_plan
                if self.move_mode in ("arm", "trajectory"):
                    selector.moved(q_start, view)
                else:
                    selector.take(view.choice)
                self._last_arm_plan = None
                # the move's joint states now, while the exploration waits for a new grid, not in the next plan
                for swept_by, fed in self._selectors.values():
                    if swept_by is selector:
                        self._sweep_seen(selector, fed)

    def destroy_node(self) -> None:
        if self._streams is not None:
            self._streams.destroy()
        super().destroy_node()

    # -- planning -----------------------------------------------------------------------------
    def plan(self, request: PlanNextBestView.Request, interrupt: Interrupt | None = None) -> PlanNextBestView.Response:
        """Plan on the latest grid; never raises (errors go into the response). The waits for the
        servers end when ``interrupt`` (default: the node's shutdown) is triggered."""
        interrupt = interrupt or self._shutdown
        response = PlanNextBestView.Response()
        start = time.perf_counter()
        self.server_times.clear()
        try:
            grid = self._grid.latest()
            state, geometry = msg_to_grid(grid)
            frame = grid.header.frame_id or self.frame_id
            method = ros_method(request.method, self.method)
            frustum = self._sensor.frustum()
            context = planning_context(
                self.dataset, geometry, self.backend, self.n_rays, self._rng,
                frustum.hfov_deg, frustum.vfov_deg, frustum.max_range_m, frustum.min_range_m,
            )  # fmt: skip
            context.gain_variant = self.gain_variant
            self.config.apply_sensor_model(context, geometry.resolution)
            box_min, box_max = self._planning_box(request)
            top_k = max(1, int(request.top_k), self.markers_top_k)
            keep = origin_filter(geometry, box_min is not None, box_min, box_max, int(request.max_origins), self._rng)
            planner = RecordingPlanner(make_planner(method.name), keep, self._height_limit(geometry))
            if not self.in_process:
                hooks = self._server_hooks(grid, state, geometry, request, context, planner, interrupt)
                context.completion, context.ranker = hooks
            report = None
            if self._arm is None and self._view_guard is None:
                planner.rank(state, context, top_k)
            elif self._arm is None:  # never a view the running exploration has ruled out
                planner.ranked = self._view_guard.rank(planner, state, context, top_k)
            else:
                current_q, _ = self._joints.current()  # raises on missing / wrong joint states
                with self._arm_lock:
                    selector = self._selector(geometry)
                    report = selector.select(planner, state, context, current_q, max(top_k, self.arm_top_k))
                    self._last_arm_plan = None if report.view is None else (selector, current_q, report.view)
                self.get_logger().info(f"arm check: {report.summary()}")
            ranked = planner.ranked
            # messages only for the views the response and the markers show (arm_top_k may rank 20 000)
            views = [(*view_pose(c, context, geometry), c.gain) for c in ranked[: max(top_k, 1)]]
            if ranked:
                t = ranked[0].times
                response.time_cnn_s, response.time_raycast_s, response.time_views_s = t["cnn"], t["raycast"], t["views"]
                response.time_rank_s = max(0.0, planner.seconds - t["cnn"])
            if report is not None:
                response.time_capability_s = report.times.get("capability", 0.0)
                response.time_ik_collision_s = report.times.get("ik_collision", 0.0)
                response.arm_checked = int(report.checked)
            if not views:
                raise ValueError(NO_POSITIVE_GAIN)
            ranked_msgs = [
                ViewScore(pose=arrays_to_pose_stamped(p, q, frame, grid.header.stamp), gain=float(g))
                for p, q, g in views
            ]
            response.best_pose, response.best_gain = ranked_msgs[0].pose, ranked_msgs[0].gain
            if report is not None:
                if report.view is None:
                    raise ValueError(unreachable_message(report))
                chosen = report.view.choice
                position, quaternion = view_pose(chosen, context, geometry)
                quaternion = reached_quaternion(report.view, quaternion)  # the arm may take it turned about its axis
                pose = arrays_to_pose_stamped(position, quaternion, frame, grid.header.stamp)
                response.best_pose, response.best_gain = pose, float(chosen.gain)
                response.reachable = True
                response.joint_goal = joint_state_msg(self._arm.robot, report.view.q)
                response.joint_goal.header.stamp = grid.header.stamp
                response.joint_goal.header.frame_id = frame
                response.joint_path_length = report.view.path_length
            response.ranked = ranked_msgs[: max(1, int(request.top_k))]
            self._last_choice = ranked[0] if report is None else report.view.choice
            response.success = True
            self._nbv_pub.publish(response.best_pose)
            sensor = context.active_sensor
            depth = sensor.r_max * geometry.resolution * 0.5
            self._marker_pub.publish(
                planning_markers(frame, grid.header.stamp, views[: self.markers_top_k], sensor.hfov_deg,
                                 sensor.vfov_deg or 0.0, depth, 4 * geometry.resolution)
            )  # fmt: skip
        except (ValueError, TimeoutError, RuntimeError, WaitInterruptedError) as exc:
            response.success = False
            response.message = str(exc)
            self.get_logger().warning(f"plan: {exc}")
        response.time_total_s = time.perf_counter() - start
        return response

    def _planning_box(self, request) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The camera workspace of a plan: the request's box (``use_workspace``) ∩ the
        ``workspace_min/max`` parameters ∩ the camera heights; (None, None) when nothing limits it."""
        boxes = [] if self._workspace is None else [self._workspace]
        if request.use_workspace:
            low, high = request.workspace_min, request.workspace_max
            boxes.append((np.array([low.x, low.y, low.z]), np.array([high.x, high.y, high.z])))
        low_z, high_z = self.min_camera_height_m, self.max_camera_height_m
        if low_z or high_z:
            boxes.append((np.array([-UNBOUNDED, -UNBOUNDED, low_z or -UNBOUNDED]),
                          np.array([UNBOUNDED, UNBOUNDED, high_z or UNBOUNDED])))  # fmt: skip
        if not boxes:
            return None, None
        return np.max([b[0] for b in boxes], axis=0), np.min([b[1] for b in boxes], axis=0)

    def _height_limit(self, geometry):
        """use_arm: the origin filter of ``arm_min_view_height_m`` (None when off)."""
        low = self.arm_min_view_height_m
        if self._arm is None or low <= 0:
            return None
        return lambda origins: origins[geometry.cell_centre(origins)[:, 2] >= low]

    def _server_hooks(
        self,
        grid: VoxelGrid,
        original: np.ndarray,
        geometry,
        request: PlanNextBestView.Request,
        context,
        planner,
        interrupt: Interrupt,
    ):
        """Completion (``/nbv/complete``) and ranking (``/nbv/rank_views``) hooks of the core
        planner; the arm's capability filter (``planner.arm_filter``) travels as allowed origins.
        ``original`` is ``grid``'s state: a planner's grid that differs from it (swept space
        carved) travels as a grid message of its own."""
        completed = {}
        carved: list = []  # (state, message) of the planner's grid when it differs (swept space carved)
        box_min, box_max = self._planning_box(request)

        def grid_msg(state: np.ndarray) -> VoxelGrid:
            if state.shape == original.shape and np.array_equal(state, original):
                return grid
            if not carved or carved[0][0] is not state:
                carved[:] = [(state, grid_to_msg(state, geometry, grid.header.frame_id, grid.header.stamp))]
            return carved[0][1]

        def complete(state: np.ndarray, context) -> np.ndarray:
            call = CompleteGrid.Request(grid=grid_msg(state), dataset=self.dataset)
            reply = call_service(self, self._complete_client, call, self.service_timeout_s, interrupt)
            if not reply.success:
                raise ValueError(f"completion failed: {reply.message}")
            prob, _ = msg_to_probability(reply.probability)
            completed["msg"], completed["prob"] = reply.probability, prob
            self.server_times.update(cnn_server=reply.time_total_s, cnn_inference=reply.inference_time_s)
            return prob

        def rank(method: str, state: np.ndarray, prob, top_k: int) -> list:
            call = RankViews.Request(
                grid=grid_msg(state), method=method, top_k=top_k, use_workspace=box_min is not None, compact=True
            )
            if box_min is not None:
                call.workspace_min = Point(x=float(box_min[0]), y=float(box_min[1]), z=float(box_min[2]))
                call.workspace_max = Point(x=float(box_max[0]), y=float(box_max[1]), z=float(box_max[2]))
            call.max_origins = request.max_origins
            if planner.arm_filter is not None and (self.capability_stride or self.arm_min_view_height_m > 0):
                allowed_cells = planner.arm_filter(context.candidate_origins(state))
                allowed = flat_cells(allowed_cells, state.shape)
                call.allowed_origins = array.array("I", allowed.astype(np.uint32).tobytes())
                if planner.view_mask is not None:  # the capability map's orientations, never a taken view
                    mask = view_mask_to_bytes(allowed, planner.view_mask(allowed_cells))
                    call.allowed_views = array.array("B", mask)
            if prob is not None:
                call.probability = (
                    completed["msg"]
                    if prob is completed.get("prob")
                    else probability_to_msg(prob, geometry, grid.header.frame_id, grid.header.stamp)
                )
            reply = call_service(self, self._rank_client, call, self.service_timeout_s, interrupt)
            if not reply.success:
                raise ValueError(f"ranking failed: {reply.message}")
            if len(reply.ranked_gains) or not len(reply.ranked):  # the compact arrays (an older server: messages)
                choices = ranked_from_arrays(np.frombuffer(reply.ranked_cells, dtype=np.uint32),
                                             np.frombuffer(reply.ranked_orientations, dtype=np.uint16),
                                             np.frombuffer(reply.ranked_gains, dtype=np.float32), state.shape,
                                             len(context.orientations))  # fmt: skip
            else:
                choices = [choice_from_pose(*pose_to_arrays(v.pose.pose), v.gain, context, geometry)
                           for v in reply.ranked]  # fmt: skip
            for choice in choices:
                choice.times.update(raycast=reply.time_raycast_s, views=reply.time_views_s)
            self.server_times["rank_server"] = reply.time_total_s
            return choices

        return complete, rank

    def _plan_service(self, request, response):
        result = self.plan(request)
        for field in result.get_fields_and_field_types():
            setattr(response, field, getattr(result, field))
        return response

    # -- exploration --------------------------------------------------------------------------
    def _check_goal(self, goal: Explore.Goal) -> GoalResponse:
        """Refuse goals that cannot run, and every goal while an exploration runs or was just
        accepted (one at a time: the client learns it from the goal response; the reason is
        logged). An accepted goal holds the exploration slot until :meth:`_explore` ends it."""
        if goal.max_views < 1 or not np.isfinite(goal.stop_unknown_fraction) or not np.isfinite(goal.stop_gain):
            self.get_logger().warning("explore: rejected a goal with max_views < 1 or non-finite thresholds")
            return GoalResponse.REJECT
        with self._explore_lock:
            claimed = self._goal_accepted_at is not None and time.monotonic() - self._goal_accepted_at < GOAL_CLAIM_S
            if self._active_goal is not None or claimed:
                self.get_logger().warning("explore: rejected a goal: another exploration is running (one at a time)")
                return GoalResponse.REJECT
            self._goal_accepted_at = time.monotonic()
        return GoalResponse.ACCEPT

    def _cancel_goal(self, goal_handle) -> CancelResponse:
        """Accept every cancel request; the running exploration's waits end at once (rclpy marks
        the goal CANCELING right after this returns, :meth:`_explore` waits for that)."""
        with self._explore_lock:
            interrupt = self._goal_interrupt if goal_handle is self._active_goal else None
            if interrupt is None:
                self._canceled_before_start = goal_handle
        if interrupt is not None:
            interrupt.trigger(GOAL_CANCELED)
        return CancelResponse.ACCEPT

    def _move_arm(self, goal: JointState, interrupt: Interrupt) -> int:
        """Send the joint goal to ``arm_sim/move_to_joints``; wait until ``joint_states`` reach it
        and return the stamp (ns) of the first joint state there (frames stamped at or after it
        are taken at the goal)."""
        goal_q = np.asarray(goal.position, dtype=np.float64)
        sent = self.get_clock().now().nanoseconds
        request = MoveToJoints.Request(name=list(goal.name), position=list(goal.position))
        reply = call_service(self, self._joints_client, request, self.move_timeout_s, interrupt)
        if not reply.success:
            raise ExecutionError(f"arm move failed: {reply.message}")
        try:
            timeout_s = self.move_timeout_s + reply.duration_s
            return self._joints.wait_until(goal_q, self.joint_tolerance, sent, timeout_s, interrupt)
        except TimeoutError as exc:
            raise ExecutionError(str(exc)) from exc

    def _move(self, planned: PlanNextBestView.Response, interrupt: Interrupt) -> int:
        """Move to a plan's view in ``move_mode``; returns the stamp (ns) from which frames are taken there.

        Raises:
            ExecutionError: the arm / controller did not take the view (the next view is tried).
            WaitInterruptedError: the goal was canceled or the node shuts down meanwhile.
        """
        if self.move_mode == "arm":
            return self._move_arm(planned.joint_goal, interrupt)
        if self.move_mode == "trajectory":
            try:
                return self._move_trajectory(planned.joint_goal, interrupt)
            except TimeoutError as exc:
                raise ExecutionError(str(exc)) from exc
        return self._move_camera(planned.best_pose, interrupt)

    def _rule_out_planned_view(self) -> None:
        """The move to the last plan's view failed: never plan that view again."""
        with self._arm_lock:
            if self._last_arm_plan is not None:
                selector, _, view = self._last_arm_plan
                selector.take(view.choice)
                self._last_arm_plan = None

    def _move_trajectory(self, goal: JointState, interrupt: Interrupt) -> int:
        """Send the straight joint path from the plan's start to ``goal``, timed within the limits,
        to the FollowJointTrajectory action; wait for the result and for ``joint_states`` at the
        goal; returns the stamp (ns) of the first joint state there.

        Raises:
            ExecutionError: the server is missing, rejects the goal or reports a failure.
        """
        with self._arm_lock:
            plan = self._last_arm_plan
        if plan is None:
            raise ExecutionError("no planned joint path to execute")
        robot = self._arm.robot
        q_start, q_goal = plan[1], robot.joint_state_configuration(goal.name, goal.position)
        path = self._timed_path(q_start, q_goal, plan[2].waypoints)
        joints = self._controller_joints()
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
        request.goal_tolerance = [JointTolerance(name=n, position=self.goal_tolerance) for n in joints]
        request.goal_time_tolerance = duration_msg(self.move_timeout_s)
        client = self._trajectory_client
        if not interrupt.wait_until(client.server_is_ready, min(self.move_timeout_s, 10.0)):
            raise ExecutionError(f"action {self.trajectory_action} is not available")
        sent = self.get_clock().now().nanoseconds
        handle = wait_future(client.send_goal_async(request), self.move_timeout_s, "goal acceptance", interrupt)
        if handle is None or not handle.accepted:
            raise ExecutionError(f"{self.trajectory_action} rejected the trajectory (see the controller's log)")
        try:
            outcome = wait_future(
                handle.get_result_async(), path.duration + 2 * self.move_timeout_s, "trajectory result", interrupt
            )
        except WaitInterruptedError:
            handle.cancel_goal_async()  # the arm stops too (the answer is not awaited)
            raise
        code, text = outcome.result.error_code, outcome.result.error_string
        if outcome.status != GoalStatus.STATUS_SUCCEEDED or code != FollowJointTrajectory.Result.SUCCESSFUL:
            raise ExecutionError(
                f"{self.trajectory_action} failed: error code {code} {text!r} (status {outcome.status})"
            )
        tolerance = max(self.joint_tolerance, self.goal_tolerance)
        return self._joints.wait_until(q_goal, tolerance, sent, self.move_timeout_s, interrupt)

    def _controller_joints(self) -> list[str]:
        """The joints a trajectory names: ``controller_joints``, or the camera chain's."""
        robot = self._arm.robot
        joints = [n for n in self.controller_joints if n] or [robot.joint_names[i] for i in robot.chain]
        unknown = sorted(set(joints) - set(robot.joint_names))
        if unknown:
            raise ExecutionError(f"controller_joints: {unknown} are not joints of the robot {robot.joint_names}")
        return joints

    def _timed_path(self, q_start: np.ndarray, q_goal: np.ndarray, waypoints: np.ndarray | None = None) -> TimedPath:
        """The joint path (straight, or a planned path's ``waypoints``) timed within
        ``trajectory_velocity_scale`` × the URDF velocity limits and the acceleration and jerk limits."""
        robot = self._arm.robot
        vmax = np.asarray(robot.model.velocityLimit, dtype=np.float64) * self.trajectory_velocity_scale
        points = np.stack([q_start, q_goal]) if waypoints is None else np.asarray(waypoints, dtype=np.float64)
        return time_parameterise_path(points, vmax, self.max_joint_acceleration, self.max_joint_jerk,
                                      self.trajectory_dt_s)  # fmt: skip

    def _move_camera(self, target: PoseStamped, interrupt: Interrupt) -> int:
        """Move the camera; returns the stamp (ns) of the first frame taken at the target."""
        if self.move_mode == "service":
            request = MoveCamera.Request(target=target)
            reply = call_service(self, self._move_client, request, self.move_timeout_s, interrupt)
            if not reply.success:
                raise ValueError(f"camera move failed: {reply.message}")
            return stamp_ns(reply.frame_stamp)
        goal_position, _ = pose_to_arrays(target.pose)
        self._goal_pub.publish(target)
        sent = self.get_clock().now().nanoseconds

        frame = target.header.frame_id or self.frame_id
        reached: list[int] = []

        def arrived() -> bool:
            current = self._camera_position(frame)
            if current is None or current[1] < sent:
                return False
            if float(np.linalg.norm(current[0] - goal_position)) > self.arrival_tolerance_m:
                return False
            reached.append(current[1])
            return True

        with self._camera_lock:
            if not interrupt.wait_for(self._camera_lock, arrived, self.move_timeout_s):
                raise TimeoutError(f"camera did not report arrival within {self.move_timeout_s:.0f} s")
            return reached[-1]

    def _new_view_guard(self, shape: tuple[int, ...]) -> ViewGuard | None:
        """The view guard of one exploration (``guard_min_cells``; None when 0 = off). With
        ``use_arm`` the arm's selector never plans a taken view again anyway; the guard then only
        counts the views that changed too little (feedback ``ruled_out_views``)."""
        if self.guard_min_cells == 0:
            return None
        return ViewGuard.for_grid(shape, None if self.guard_min_cells < 0 else self.guard_min_cells)

    def _explore(self, goal_handle) -> Explore.Result:
        """Run one exploration; the goal ends SUCCEEDED when a stop condition is met, CANCELED
        when the client cancels, ABORTED on any error (with the error as ``reason_stopped``)."""
        goal: Explore.Goal = goal_handle.request
        result = Explore.Result()
        interrupt = self._shutdown.child()  # triggered by a cancel request (_cancel_goal) or the shutdown
        with self._explore_lock:
            self._active_goal, self._goal_interrupt, self._goal_accepted_at = goal_handle, interrupt, None
            if self._canceled_before_start is goal_handle:
                interrupt.trigger(GOAL_CANCELED)
            self._canceled_before_start = None
        try:
            outcome, result.reason_stopped, fraction = self._run_exploration(goal_handle, goal, result, interrupt)
            result.views = len(result.poses)
            result.final_unknown_fraction = float(fraction)
            if outcome == "canceled" and not cancel_requested(goal_handle, 1.0):
                outcome = "aborted"  # never happens: rclpy marks an accepted cancel right after _cancel_goal
                result.reason_stopped += " (the cancel request did not reach the goal's state)"
            if outcome == "canceled":
                goal_handle.canceled()
            elif outcome == "aborted":
                goal_handle.abort()
            else:
                goal_handle.succeed()
        finally:
            with self._explore_lock:
                self._active_goal = self._goal_interrupt = None
            interrupt.release()
        return result

    def _run_exploration(
        self, goal_handle, goal: Explore.Goal, result: Explore.Result, interrupt: Interrupt
    ) -> tuple[str, str, float]:
        """The exploration loop; returns (outcome: succeeded/canceled/aborted, reason, unknown
        fraction). Every wait of a step (grid, servers, move, joint states) ends at once when
        ``interrupt`` is triggered: CANCELED after a cancel request, ABORTED on shutdown."""
        fraction = 1.0
        index, failures = 0, 0  # views taken; failed moves in a row
        try:
            previous = msg_to_grid(self._grid.wait_for_stamp(0, self.grid_timeout_s, interrupt))[0]
            fraction = unknown_fraction_all(previous)
            guard = self._view_guard = self._new_view_guard(previous.shape)
            if self._joints is not None:  # the arm's first joint state may still be on its way
                self._joints.wait_for_first(self.move_timeout_s, interrupt)
            while index < goal.max_views:
                if goal_handle.is_cancel_requested:
                    return "canceled", f"canceled after {index} views", fraction
                if goal.stop_unknown_fraction > 0 and fraction <= goal.stop_unknown_fraction:
                    return "succeeded", f"unknown fraction {fraction:.4f} <= {goal.stop_unknown_fraction}", fraction
                planned = self.plan(goal_plan_request(goal), interrupt)
                interrupt.check()  # a plan interrupted while it waited for a server answers an error
                if not planned.success:
                    if planned.message == NO_POSITIVE_GAIN or planned.message.startswith(NO_REACHABLE_VIEW):
                        ruled = len(guard.ruled_out) if guard is not None else 0
                        reason = planned.message + (f" ({ruled} ruled out by the view guard)" if ruled else "")
                        return "succeeded", reason, fraction
                    return "aborted", f"error: planning failed: {planned.message}", fraction
                if planned.best_gain <= goal.stop_gain:
                    return "succeeded", f"best gain {planned.best_gain:.4f} <= {goal.stop_gain}", fraction
                moving = time.perf_counter()
                try:
                    frame_ns = self._move(planned, interrupt)
                except ExecutionError as exc:
                    failures += 1
                    result.failed_executions += 1
                    self._rule_out_planned_view()
                    failed = Explore.Feedback(
                        view_index=index, pose=planned.best_pose, gain=planned.best_gain, unknown_fraction=fraction,
                        executed=False, execution_error=str(exc),
                    )  # fmt: skip
                    failed.joint_goal, failed.joint_travel = planned.joint_goal, planned.joint_path_length
                    goal_handle.publish_feedback(failed)
                    self.get_logger().warning(f"view {index}: move failed ({exc}); trying the next ranked view")
                    if failures >= self.max_failed_executions:
                        return (
                            "succeeded",
                            f"stopped: {failures} planned views in a row failed to execute ({exc})",
                            fraction,
                        )
                    continue
                failures = 0
                if self._arm is not None:
                    self._took_planned_view()
                waiting = time.perf_counter()
                grid = self._grid.wait_for_stamp(frame_ns, self.grid_timeout_s, interrupt)
                done = time.perf_counter()
                seen = msg_to_grid(grid)[0]
                fraction = unknown_fraction_all(seen)
                changed = int(np.count_nonzero(seen != previous)) if seen.shape == previous.shape else seen.size
                previous = seen
                if guard is not None and self._last_choice is not None:
                    guard.record(self._last_choice, changed)
                result.poses.append(planned.best_pose)
                feedback = Explore.Feedback(
                    view_index=index, pose=planned.best_pose, gain=planned.best_gain, unknown_fraction=fraction,
                    executed=True, ruled_out_views=0 if guard is None else len(guard.ruled_out),
                )  # fmt: skip
                if self.move_mode in ("arm", "trajectory"):
                    feedback.joint_goal, feedback.joint_travel = planned.joint_goal, planned.joint_path_length
                goal_handle.publish_feedback(feedback)
                self.get_logger().info(
                    f"view {index}: gain {planned.best_gain:.4f}, unknown fraction {fraction:.4f}, "
                    f"{changed} cells changed; {stage_times(planned, waiting - moving, done - waiting)}"
                    f"{server_stage_times(self.server_times)}"
                )
                index += 1
        except WaitInterruptedError as exc:
            if interrupt.reason == GOAL_CANCELED:
                self.get_logger().info(f"explore: canceled after {index} views")
                return "canceled", f"canceled after {index} views", fraction
            self.get_logger().warning(f"explore: stopped after {index} views: {exc}")
            return "aborted", f"stopped after {index} views: {exc}", fraction
        except (ValueError, TimeoutError, RuntimeError) as exc:
            self.get_logger().error(f"explore: {exc}")
            return "aborted", f"error: {exc}", fraction
        finally:
            self._view_guard = None
        if goal_handle.is_cancel_requested:
            return "canceled", f"canceled after {goal.max_views} views", fraction
        return "succeeded", f"reached {goal.max_views} views", fraction


def workspace_box(low: list, high: list) -> tuple[np.ndarray, np.ndarray] | None:
    """The ``workspace_min`` / ``workspace_max`` parameters as a box (None when both are empty).

    Raises:
        ValueError: not three finite numbers each, or min > max.
    """
    if not low and not high:
        return None
    lo, hi = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError(f"workspace_min/workspace_max: expected 3 finite numbers each, got {low} and {high}")
    if np.any(lo > hi):
        raise ValueError(f"workspace_min {low} exceeds workspace_max {high} on some axis")
    return lo, hi


def goal_plan_request(goal: Explore.Goal) -> PlanNextBestView.Request:
    """The planning request of one exploration step: the goal's method and workspace (its box
    and camera heights; 0 heights = no limit from the goal)."""
    request = PlanNextBestView.Request(method=goal.method, use_workspace=goal.use_workspace)
    low, high = goal.workspace_min, goal.workspace_max
    box_min = [low.x, low.y, low.z] if goal.use_workspace else [-UNBOUNDED] * 3
    box_max = [high.x, high.y, high.z] if goal.use_workspace else [UNBOUNDED] * 3
    if goal.min_camera_height:
        box_min[2] = max(box_min[2], float(goal.min_camera_height))
    if goal.max_camera_height:
        box_max[2] = min(box_max[2], float(goal.max_camera_height))
    request.use_workspace = bool(goal.use_workspace or goal.min_camera_height or goal.max_camera_height)
    request.workspace_min = Point(x=float(box_min[0]), y=float(box_min[1]), z=float(box_min[2]))
    request.workspace_max = Point(x=float(box_max[0]), y=float(box_max[1]), z=float(box_max[2]))
    return request


def duration_msg(seconds: float) -> Duration:
    """``builtin_interfaces/Duration`` of a non-negative number of seconds."""
    nanoseconds = round(seconds * 1e9)
    return Duration(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def wait_future(future, timeout_s: float, what: str, interrupt: Interrupt):
    """The result of an rclpy future completed by the executor's other threads.

    Raises:
        ExecutionError: not done within ``timeout_s``, or it raised.
        WaitInterruptedError: ``interrupt`` was triggered first.
    """
    if not interrupt.wait_future(future, timeout_s):
        raise ExecutionError(f"no {what} within {timeout_s:.0f} s")
    if future.exception() is not None:
        raise ExecutionError(f"{what} failed: {future.exception()}")
    return future.result()


def cancel_requested(goal_handle, timeout_s: float) -> bool:
    """Whether the goal is CANCELING, waiting up to ``timeout_s`` for rclpy to mark it (it does so
    right after the cancel callback that woke the exploration returned)."""
    deadline = time.monotonic() + timeout_s
    while not goal_handle.is_cancel_requested:
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.002)
    return True


def stage_times(planned: PlanNextBestView.Response, move_s: float, grid_wait_s: float) -> str:
    """Where one exploration step's time went, for the log: planning (its CNN, ray casting and
    view search; with the ranking's and the arm's times in the response also the rest of the
    ranking (transport, reply), the capability map and the IK/collision checks; the rest being
    message conversion), the move, and the wait for a grid that includes a frame from the new pose."""
    parts = (planned.time_cnn_s, planned.time_raycast_s, planned.time_views_s)
    arm = planned.time_capability_s + planned.time_ik_collision_s
    ranking = ""
    if planned.time_rank_s or arm:
        reply = max(0.0, planned.time_rank_s - parts[1] - parts[2])
        ranking = (
            f", rank reply {reply:.2f}, capability {planned.time_capability_s:.2f}, IK+collision "
            f"{planned.time_ik_collision_s:.2f} ({planned.arm_checked} checked)"
        )
        rest = max(0.0, planned.time_total_s - parts[0] - max(planned.time_rank_s, parts[1] + parts[2]) - arm)
    else:
        rest = max(0.0, planned.time_total_s - sum(parts))
    return (
        f"plan {planned.time_total_s:.2f} s (CNN {parts[0]:.2f}, ray casting {parts[1]:.2f}, views {parts[2]:.2f}"
        f"{ranking}, other {rest:.2f}), move {move_s:.2f} s, grid wait {grid_wait_s:.2f} s"
    )


def server_stage_times(times: dict[str, float]) -> str:
    """The servers' own times on the last plan's requests (``time_total_s`` of /nbv/complete and
    /nbv/rank_views, the completion's inference time), for the log: set beside the planner's
    round trips they show what the transport costs; empty when the plan made no such request."""
    parts = []
    if "cnn_server" in times:
        parts.append(f"completion server {times['cnn_server']:.2f} (inference {times['cnn_inference']:.2f})")
    if "rank_server" in times:
        parts.append(f"ranking server {times['rank_server']:.2f}")
    return f"; servers: {', '.join(parts)}" if parts else ""


def unreachable_message(report: FeasibilityReport) -> str:
    """Why ``use_arm`` planning found nothing, with the counts of the exact stage."""
    budget = ", check budget spent" if report.budget_exhausted else ""
    budget += ", near the camera too" if report.fallback else ""
    return (
        f"{NO_REACHABLE_VIEW}: {report.checked} ranked views checked ({report.unreachable} without IK solution, "
        f"{report.in_collision} in collision, {report.path_blocked} with a blocked path{budget})"
    )


def main(args: list[str] | None = None) -> int:
    return run_node(NbvPlanner, args)


if __name__ == "__main__":
    raise SystemExit(main())
