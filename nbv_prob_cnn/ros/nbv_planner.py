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
  (``trajectory_action``, default ``/arm_controller/follow_joint_trajectory``), or with
  ``move_mode:=moveit`` hand the view to MoveIt 2's ``move_group`` as a ``moveit_msgs/MoveGroup``
  pose or joint goal (:mod:`~nbv_prob_cnn.ros.moveit_mover`)),
  wait for a grid that includes a frame from the new pose, repeat until a stop condition.
  A move that is rejected or fails (arm / trajectory / moveit modes) rules that view out and the next
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
joint goal. A fallback plan's times and ``arm_checked`` count both passes (the first ranking and
check, then the one near the camera), and its ``message`` says what the first pass found
(``fallback after 300 checked: 300 in collision``, also in the view's log line). The planner's
grid (not the integrator's) counts as free the cells the arm's bodies filled at the configurations
seen on ``/joint_states`` and along the moves the exploration commanded (``arm_carve_swept``); a
view the exploration moved to is never planned again.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from functools import partial

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped, TransformStamped
from nbv_prob_cnn_msgs.action import Explore
from nbv_prob_cnn_msgs.msg import ViewScore, VoxelGrid
from nbv_prob_cnn_msgs.srv import PlanNextBestView
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from nbv_prob_cnn.arm.arm_session import ArmBookkeepingMover, ArmSession, unreachable_message
from nbv_prob_cnn.arm.feasibility import reached_quaternion
from nbv_prob_cnn.arm.path_planning import PathPlannerSettings
from nbv_prob_cnn.arm.views import ArmPlanningSetup
from nbv_prob_cnn.basics.camera import DATASETS
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.interrupt import Interrupt, WaitInterruptedError
from nbv_prob_cnn.basics.modes import CNN_PRECISIONS, MOVE_MODES, Backend, MoveMode
from nbv_prob_cnn.basics.results import no_view_reason
from nbv_prob_cnn.exploration.session import (
    ExplorationSession,
    FailedMove,
    Mover,
    Outcome,
    TakenView,
)
from nbv_prob_cnn.exploration.slot import ExplorationSlot
from nbv_prob_cnn.exploration.step_log import fallback_note, server_stage_times, stage_times
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.planners import ViewChoice, check_ros_method, make_planner, ros_method
from nbv_prob_cnn.planners.base import OriginFilter
from nbv_prob_cnn.planners.recording import RecordingPlanner
from nbv_prob_cnn.planners.registry import DEFAULT_METHOD
from nbv_prob_cnn.planners.requests import origin_filter, view_pose
from nbv_prob_cnn.planners.surface_stop import SurfaceStop
from nbv_prob_cnn.planners.workspace import Box, height_box, intersect_boxes, workspace_box
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.camera_sensor import CameraInfoSensor, SensorParams, node_planning_context
from nbv_prob_cnn.ros.conversions import arrays_to_pose_stamped, geometry_of, msg_to_grid
from nbv_prob_cnn.ros.explore_parts import NO_POSITIVE_GAIN, ExploreGrids, GoalPlanner, cancel_requested
from nbv_prob_cnn.ros.gain_params import (
    backend_param,
    gain_variant_param,
    image_rerank_param,
    n_rays_param,
    surface_blend_param,
)
from nbv_prob_cnn.ros.grid_holder import GridSourceParams, LatestGrid, grid_transport_param
from nbv_prob_cnn.ros.joint_state_intake import JointStateIntake
from nbv_prob_cnn.ros.markers import planning_markers
from nbv_prob_cnn.ros.moveit_mover import MoveGroupMover, MoveItParams
from nbv_prob_cnn.ros.movers import (
    CameraPosition,
    CameraServiceMover,
    CameraTopicMover,
    JointGoalMover,
    TrajectoryMover,
)
from nbv_prob_cnn.ros.parameters import declare_config, param, positive_seconds
from nbv_prob_cnn.ros.readiness import READY, SETTING_UP, ReadinessPublisher
from nbv_prob_cnn.ros.remote_planning import RemotePlanning
from nbv_prob_cnn.ros.robot_params import ArmViewParams, joint_state_msg
from nbv_prob_cnn.ros.runtime import run_node, shutdown_interrupt
from nbv_prob_cnn.ros.stream_node import StreamNode
from nbv_prob_cnn.ros.tf_listener import POSE_SOURCES, TfListener

#: The move modes that move the arm to the planned configuration (they need use_arm).
ARM_MOVE_MODES = ("arm", "trajectory", "moveit")


@dataclass
class PlannerConfig(GridSourceParams, SensorParams, ArmViewParams, MoveItParams):
    """Parameters of ``nbv_planner`` (``method`` and ``service_timeout_s`` may change at run time):
    where grids come from (:class:`GridSourceParams`), the robot description and ``use_arm``
    (:class:`ArmViewParams`), the planning frustum (:class:`SensorParams`: CameraInfo + range),
    ``move_mode:=moveit``'s (:class:`MoveItParams`), then these."""

    pose_source: str = param(
        "tf", "camera pose (move_mode topic: arrival): tf (camera_frame in the grid frame, newest) or topic "
        "(/camera/pose)", choices=POSE_SOURCES,
    )  # fmt: skip
    dataset: str = param("3dt", "sensor/ray defaults and CNN weights", choices=tuple(sorted(DATASETS)))
    method: str = param(DEFAULT_METHOD, "method when a request names none", dynamic=True, check=check_ros_method)
    in_process: bool = param(False, "complete and ray-cast here instead of via the servers")
    backend: Backend = backend_param("ray-casting backend (in-process mode)")
    n_rays: int = n_rays_param("ray sub-cells per side (0 = default)")
    gain_variant: str = gain_variant_param(
        "gain in-process ('paper' or 'original', docs/original_code.md; else gain_server's)"
    )
    surface_blend: float = surface_blend_param(
        "the surface methods' blend in-process (0 the paper's gain, 1 the surface alone; else gain_server's)"
    )
    image_rerank: int = image_rerank_param(
        "the surface methods re-rank the search's best this many views by their own image rays in-process "
        "(0: none; else gain_server's)"
    )
    frame_id: str = param("world", "frame of grids that carry none")
    grid_transport: str = grid_transport_param()
    service_timeout_s: float = param(
        60.0, "completion/ranking wait", min_value=0.1, max_value=600.0, dynamic=True, check=positive_seconds
    )
    move_mode: MoveMode = param(
        "service",
        "'service' (sim_camera/move_to), 'topic' (goal pose), 'arm' (arm_sim/move_to_joints), 'trajectory' "
        "(FollowJointTrajectory) or 'moveit' (MoveIt 2's MoveGroup action); arm, trajectory and moveit need use_arm",
        choices=MOVE_MODES,
    )  # fmt: skip
    workspace_min: list = param([], "camera workspace box corner [x, y, z] (grid frame, m; [] = no box)")
    workspace_max: list = param([], "camera workspace box corner [x, y, z] (grid frame, m; [] = no box)")
    cnn_window: int = param(
        -1, "CNN window: the CNN completes only the candidate cells' box grown by this margin (cells; 48 = "
        "3DT's receptive field), unknown cells outside take p0: a cost that follows the workspace in a room; "
        "-1 = off (every cell the rays read)", min_value=-1, max_value=100000,
    )  # fmt: skip
    cnn_precision: str = param(
        "float32", "the CNN's arithmetic when it runs in this node (in_process): float32 (as trained) or bfloat16 "
        "(faster on CPUs with AVX512-BF16 or AMX); through the servers completion_server's precision applies",
        choices=CNN_PRECISIONS,
    )  # fmt: skip
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
        5, "arm / trajectory / moveit modes: views in a row whose move failed before the exploration stops",
        min_value=1, max_value=1000,
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
        self.config = cfg = declare_config(self, PlannerConfig, mirror=False)
        self._rng = np.random.default_rng()
        self._slot = ExplorationSlot()  # one exploration at a time
        self._shutdown = shutdown_interrupt(self)  # triggered by run_node when the node stops
        if cfg.move_mode in ARM_MOVE_MODES and not cfg.use_arm:
            raise ValueError(
                f"move_mode {cfg.move_mode!r} needs use_arm:=true (the joint goal comes from planning with the arm)"
            )
        self._workspace = workspace_box(cfg.workspace_min, cfg.workspace_max)  # raises on bad values
        self._arm: ArmSession | None = None
        self._joints: JointStateIntake | None = None
        group = ReentrantCallbackGroup()
        if cfg.use_arm:
            setup = ArmPlanningSetup(
                cfg.robot_config(self), cfg.motion_weight, cfg.free_above(), cfg.arm_max_checks, cfg.capability_stride,
                ik_alternatives=cfg.arm_ik_alternatives, strict_capability=cfg.arm_strict_capability,
                path_planning=PathPlannerSettings(timeout_s=cfg.arm_path_timeout_s)
                if cfg.move_mode == "trajectory" and cfg.arm_path_timeout_s > 0 else None,
                roll_symmetric=cfg.arm_roll_symmetric,
            )  # fmt: skip
            self._arm = ArmSession(setup, cfg.arm_carve_swept, cfg.arm_fallback_radius_m)
        # joint_states and /tf come at the robot's rate: on a side node with its own thread (stream_node)
        self._streams = StreamNode(self) if cfg.use_arm or cfg.pose_source == "tf" else None
        if self._arm is not None and self._streams is not None:
            on_configuration = self._arm.saw_configuration if cfg.arm_carve_swept else None
            self._joints = JointStateIntake(self._arm.robot, self, self._streams.node, on_configuration)
        self._grid = LatestGrid(
            self, callback_group=group, on_grid=self._prepare_arm if self._arm else None,
            transport=cfg.grid_transport, source=cfg,
        )  # fmt: skip
        # the scan of docs/nodes.md reads this expression: _streams is not None whenever pose_source is tf
        self._tf = TfListener(self._streams.node) if cfg.pose_source == "tf" else None  # type: ignore[union-attr]
        self._camera = CameraPosition(self._tf, cfg.camera_frame)
        if self._tf is None:
            self.create_subscription(TransformStamped, names.CAMERA_POSE, self._camera.receive, 10,
                                     callback_group=group)  # fmt: skip
        elif cfg.move_mode not in ARM_MOVE_MODES:  # the camera's arrival wait re-checks TF as
            self.create_timer(0.02, self._camera.receive, callback_group=group)  # /camera/pose would wake it
        self._sensor = CameraInfoSensor(self, cfg, cfg.dataset, callback_group=group)
        self._nbv_pub = self.create_publisher(PoseStamped, names.NEXT_BEST_VIEW, 10)
        self._marker_pub = self.create_publisher(MarkerArray, names.MARKERS, 10)
        self._remote = RemotePlanning(self, group)
        # only the move interface of move_mode joins the graph (with a real robot, nothing of ours but it)
        mover: Mover[PlanNextBestView.Response]
        if cfg.move_mode == "service":
            mover = CameraServiceMover(self, cfg, group)
        if cfg.move_mode == "topic":
            mover = CameraTopicMover(self, cfg, self._camera)
        if cfg.move_mode == "arm":
            assert self._joints is not None  # use_arm (checked above)
            mover = JointGoalMover(self, cfg, self._joints, group)
        if cfg.move_mode == "trajectory":
            assert self._joints is not None and self._arm is not None  # use_arm (checked above)
            mover = TrajectoryMover(self, cfg, self._joints, self._arm, group)
        if cfg.move_mode == "moveit":
            assert self._joints is not None and self._arm is not None  # use_arm (checked above)
            mover = MoveGroupMover(self, cfg, self._joints, self._arm, group)
        arm_moves = cfg.move_mode in ("arm", "trajectory")  # MoveIt's path is its own: only joint_states sweep it
        self._mover = mover if self._arm is None else ArmBookkeepingMover(mover, self._arm, arm_moves)
        self._readiness = ReadinessPublisher(self, ready=not cfg.use_arm, callback_group=group)
        # one plan request at a time: a plan waits for the servers' answers, which other threads of the
        # executor (4) must take; plans in parallel (a client resending while a plan runs) held every
        # thread and no answer came in until a plan timed out (the hunt: 60 s lost at load 7)
        self.create_service(
            PlanNextBestView, names.PLAN, self._plan_service, callback_group=MutuallyExclusiveCallbackGroup()
        )
        self._action = ActionServer(
            self, Explore, names.EXPLORE, execute_callback=self._explore,
            goal_callback=self._check_goal, cancel_callback=self._cancel_goal, callback_group=group,
        )  # fmt: skip
        mode = "in-process" if cfg.in_process else "via /nbv/complete and /nbv/rank_views"
        mode += f", arm {self._arm.robot.joint_names} (λ = {cfg.motion_weight:g})" if self._arm else ""
        self.get_logger().info(f"nbv_planner ready: dataset {cfg.dataset}, method {cfg.method}, {mode}")

    def _prepare_arm(self, msg: VoxelGrid) -> None:
        """use_arm: on the first grid of a geometry, load (or build) its capability map and
        collision model in a background thread, so the first plan does not wait for them (a plan
        that comes earlier waits for the thread)."""
        try:
            geometry = geometry_of(msg)
        except ValueError:
            return  # the plan reports the bad grid
        arm = self._arm
        if arm is None or not arm.claim_set_up(geometry):
            return

        def prepare() -> None:
            start = time.perf_counter()
            try:
                arm.set_up(geometry)
            except ValueError as exc:  # e.g. an arm that reaches nothing of this grid: the plan says so
                self.get_logger().warning(f"arm set-up for the grid failed: {exc}")
                self._readiness.set(DiagnosticStatus.ERROR, f"arm set-up for the grid failed: {exc}")
                return
            self.get_logger().info(f"arm set-up for the grid (capability map, collision model): "
                                   f"{time.perf_counter() - start:.1f} s")  # fmt: skip
            self._readiness.set(DiagnosticStatus.OK, READY)

        self._readiness.set(DiagnosticStatus.WARN, SETTING_UP)
        threading.Thread(target=prepare, name="arm_setup", daemon=True).start()

    def destroy_node(self) -> None:
        if self._streams is not None:
            self._streams.destroy()
        super().destroy_node()

    # -- planning -----------------------------------------------------------------------------
    def plan(
        self, request: PlanNextBestView.Request, interrupt: Interrupt | None = None, guard: ViewGuard | None = None
    ) -> tuple[PlanNextBestView.Response, ViewChoice | None]:
        """Plan on the latest grid, never a view ``guard`` ruled out; returns the response and the
        chosen view (None on failure). Never raises (errors go into the response). The waits for
        the servers end when ``interrupt`` (default: the node's shutdown) is triggered."""
        interrupt, cfg = interrupt or self._shutdown, self.config
        response, chosen = PlanNextBestView.Response(), None
        start = time.perf_counter()
        self._remote.server_times.clear()
        try:
            grid = self._grid.latest()
            state, geometry = msg_to_grid(grid)
            frame = grid.header.frame_id or cfg.frame_id
            context = node_planning_context(cfg, geometry, self._sensor.frustum(), self._rng)
            context.cnn_window = None if cfg.cnn_window < 0 else cfg.cnn_window
            context.cnn_precision = cfg.cnn_precision
            box = self._planning_box(request)
            top_k = max(1, int(request.top_k), cfg.markers_top_k)
            low, high = box if box is not None else (np.zeros(3), np.zeros(3))  # unused without a box
            # through the servers gain_server draws the origin budget itself: the planner's own candidates
            # (the CNN window's box, the arm's allowed origins) must hold every origin it may draw
            budget = int(request.max_origins) if cfg.in_process else 0
            keep = origin_filter(geometry, box is not None, low, high, budget, self._rng)
            planner = RecordingPlanner(make_planner(ros_method(request.method, cfg.method).name), keep,
                                       self._height_limit(geometry))  # fmt: skip
            if not cfg.in_process:
                context.completion, context.ranker = self._remote.hooks(
                    grid, state, geometry, context, planner, box, int(request.max_origins),
                    bool(cfg.capability_stride or cfg.arm_min_view_height_m > 0), cfg.dataset, cfg.service_timeout_s,
                    interrupt,
                )  # fmt: skip
            report = None
            if self._arm is None and guard is None:
                planner.rank(state, context, top_k)
            elif self._arm is None and guard is not None:  # never a view the running exploration has ruled out
                planner.ranked = guard.rank(planner, state, context, top_k)
            elif self._arm is not None and self._joints is not None:
                current_q, _ = self._joints.current()  # raises on missing / wrong joint states
                report = self._arm.select(planner, state, context, geometry, current_q, max(top_k, cfg.arm_top_k))
                self.get_logger().info(f"arm check: {report.summary()}")
            ranked = planner.ranked
            # messages only for the views the response and the markers show (arm_top_k may rank 20 000)
            views = [(*view_pose(c, context, geometry), c.gain) for c in ranked[: max(top_k, 1)]]
            t = planner.stage_seconds  # every rank of the plan (a near-camera fallback ranks twice)
            response.time_cnn_s, response.time_raycast_s, response.time_views_s = t["cnn"], t["raycast"], t["views"]
            response.time_rank_s = max(0.0, t["rank"] - t["cnn"])
            if report is not None:
                total = report.total()  # a fallback: both passes
                response.time_capability_s = total.times.get("capability", 0.0)
                response.time_ik_collision_s = total.times.get("ik_collision", 0.0)
                response.arm_checked = int(total.checked)
            if not views:
                raise ValueError(f"{NO_POSITIVE_GAIN}: {no_view_reason(state)}")
            ranked_msgs = [ViewScore(pose=arrays_to_pose_stamped(p, q, frame, grid.header.stamp), gain=float(g))
                           for p, q, g in views]  # fmt: skip
            response.best_pose, response.best_gain = ranked_msgs[0].pose, ranked_msgs[0].gain
            chosen = ranked[0]
            if report is not None and self._arm is not None:
                if report.view is None:
                    raise ValueError(unreachable_message(report))
                chosen = report.view.choice
                position, quaternion = view_pose(chosen, context, geometry)
                quaternion = reached_quaternion(report.view, quaternion)  # the arm may take it turned about its axis
                response.best_pose = arrays_to_pose_stamped(position, quaternion, frame, grid.header.stamp)
                response.best_gain, response.reachable = float(chosen.gain), True
                response.fallback = bool(report.fallback)  # the view is near the camera, none ranked was feasible
                response.message = report.fallback_text()  # what the first pass found ("" without a fallback)
                response.joint_goal = joint_state_msg(self._arm.robot, report.view.q)
                response.joint_goal.header.stamp, response.joint_goal.header.frame_id = grid.header.stamp, frame
                response.joint_path_length = report.view.path_length
            response.ranked = ranked_msgs[: max(1, int(request.top_k))]
            response.success = True
            self.get_logger().info(
                f"plan: {planner.name}, best gain {response.best_gain:.4g} in {time.perf_counter() - start:.2f} s"
                f"{fallback_note(response.fallback, response.message)}"
            )
            self._nbv_pub.publish(response.best_pose)
            sensor = context.active_sensor
            depth = sensor.r_max * geometry.resolution * 0.5
            self._marker_pub.publish(
                planning_markers(frame, grid.header.stamp, views[: cfg.markers_top_k], sensor.hfov_deg,
                                 sensor.vfov_deg or 0.0, depth, 4 * geometry.resolution)
            )  # fmt: skip
        except (ValueError, TimeoutError, RuntimeError, WaitInterruptedError) as exc:
            response.success, response.message, chosen = False, str(exc), None
            self.get_logger().warning(f"plan: {exc}")
        response.time_total_s = time.perf_counter() - start
        return response, chosen

    def _planning_box(self, request: PlanNextBestView.Request) -> Box | None:
        """The camera workspace of a plan: the request's box (``use_workspace``) ∩ the
        ``workspace_min/max`` parameters ∩ the camera heights; None when nothing limits it."""
        low, high = request.workspace_min, request.workspace_max
        asked = (np.array([low.x, low.y, low.z]), np.array([high.x, high.y, high.z])) if request.use_workspace else None
        heights = height_box(self.config.min_camera_height_m, self.config.max_camera_height_m)
        return intersect_boxes(self._workspace, asked, heights)

    def _height_limit(self, geometry: GridGeometry) -> OriginFilter | None:
        """use_arm: the origin filter of ``arm_min_view_height_m`` (None when off)."""
        low = self.config.arm_min_view_height_m
        if self._arm is None or low <= 0:
            return None
        return lambda origins: origins[geometry.cell_centre(origins)[:, 2] >= low]

    def _plan_service(self, request: PlanNextBestView.Request, response: PlanNextBestView.Response):
        result, _ = self.plan(request)
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
        try:
            SurfaceStop(float(goal.stop_new_surface_cells), float(goal.stop_new_surface_share))
        except ValueError as exc:
            self.get_logger().warning(f"explore: rejected a goal: {exc}")
            return GoalResponse.REJECT
        if not self._slot.claim():
            self.get_logger().warning("explore: rejected a goal: another exploration is running (one at a time)")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _cancel_goal(self, goal_handle) -> CancelResponse:
        """Accept every cancel request; the running exploration's waits end at once (rclpy marks
        the goal CANCELING right after this returns, :meth:`_explore` waits for that)."""
        self._slot.cancel(goal_handle)
        return CancelResponse.ACCEPT

    def _explore(self, goal_handle) -> Explore.Result:
        """Run one exploration (:class:`~nbv_prob_cnn.exploration.session.ExplorationSession`); the
        goal ends SUCCEEDED when a stop rule holds, CANCELED when the client cancels, ABORTED on
        shutdown or any error (with the error as ``reason_stopped``)."""
        goal: Explore.Goal = goal_handle.request
        result, cfg = Explore.Result(), self.config
        interrupt = self._shutdown.child()  # triggered by a cancel request (_cancel_goal) or the shutdown
        self._slot.start(goal_handle, interrupt)
        try:
            guard_cells = None if cfg.guard_min_cells < 0 else cfg.guard_min_cells
            stop_surface = SurfaceStop(float(goal.stop_new_surface_cells), float(goal.stop_new_surface_share))
            planner = GoalPlanner(
                self.plan, self._joints, cfg.move_timeout_s, goal, estimate_surface=stop_surface.active
            )
            session = ExplorationSession(
                ExploreGrids(self._grid, cfg.grid_timeout_s), planner, self._mover, goal.max_views,
                guard=None if cfg.guard_min_cells == 0 else partial(ViewGuard.for_grid, min_changed_cells=guard_cells),
                stop_unknown_fraction=goal.stop_unknown_fraction, stop_gain=goal.stop_gain,
                stop_surface=stop_surface, max_failed_moves=cfg.max_failed_executions, interrupt=interrupt,
                on_view=partial(self._took_view, goal_handle, result),
                on_failed_move=partial(self._move_failed, goal_handle, result),
            )  # fmt: skip
            ended = session.run()
            if ended.outcome is Outcome.CANCELED:  # (rclpy refuses two severities from one line)
                self.get_logger().info(f"explore: {ended.reason}")
            elif ended.outcome is Outcome.INTERRUPTED:
                self.get_logger().warning(f"explore: {ended.reason}")
            elif ended.outcome is Outcome.FAILED:
                self.get_logger().error(f"explore: {ended.error}")
            result.reason_stopped, result.failed_executions = ended.reason, ended.failed_moves
            result.views, result.final_unknown_fraction = len(result.poses), float(ended.unknown_fraction)
            canceled = ended.outcome is Outcome.CANCELED
            if canceled and not cancel_requested(goal_handle, 1.0):
                canceled = False  # never happens: rclpy marks an accepted cancel right after _cancel_goal
                result.reason_stopped += " (the cancel request did not reach the goal's state)"
            if canceled:
                goal_handle.canceled()
            elif ended.outcome is Outcome.SUCCEEDED:
                goal_handle.succeed()
            else:
                goal_handle.abort()
        finally:
            self._slot.finish()
            interrupt.release()
        return result

    def _took_view(self, goal_handle, result: Explore.Result, taken: TakenView[PlanNextBestView.Response]) -> None:
        """A view taken: the result's pose, the feedback and the log line with the step's times."""
        planned = taken.planned.target
        result.poses.append(planned.best_pose)
        feedback = Explore.Feedback(
            view_index=taken.index, pose=planned.best_pose, gain=planned.best_gain,
            unknown_fraction=taken.unknown_fraction, executed=True, ruled_out_views=taken.ruled_out_views,
            new_surface_cells=float("nan") if taken.planned.new_surface is None else taken.planned.new_surface,
            fallback=planned.fallback,
        )  # fmt: skip
        result.fallbacks += int(planned.fallback)
        if self.config.move_mode in ARM_MOVE_MODES:
            feedback.joint_goal, feedback.joint_travel = planned.joint_goal, planned.joint_path_length
        goal_handle.publish_feedback(feedback)
        fell_back = fallback_note(planned.fallback, planned.message)
        self.get_logger().info(
            f"view {taken.index}{fell_back}: gain {planned.best_gain:.4f}, "
            f"unknown fraction {taken.unknown_fraction:.4f}, {taken.changed_cells} cells changed; "
            f"{stage_times(planned, taken.move_s, taken.grid_wait_s)}"
            f"{server_stage_times(self._remote.server_times)}"
        )

    def _move_failed(self, goal_handle, result: Explore.Result, failed: FailedMove[PlanNextBestView.Response]) -> None:
        """A move that failed (arm / trajectory / moveit modes): the feedback says why; the next view is tried."""
        planned = failed.planned.target
        feedback = Explore.Feedback(
            view_index=failed.index, pose=planned.best_pose, gain=planned.best_gain,
            unknown_fraction=failed.unknown_fraction, executed=False, execution_error=str(failed.error),
            fallback=planned.fallback,
        )  # fmt: skip
        result.fallbacks += int(planned.fallback)
        feedback.joint_goal, feedback.joint_travel = planned.joint_goal, planned.joint_path_length
        goal_handle.publish_feedback(feedback)
        self.get_logger().warning(f"view {failed.index}: move failed ({failed.error}); trying the next ranked view")


def main(args: list[str] | None = None) -> int:
    return run_node(NbvPlanner, args)


if __name__ == "__main__":
    raise SystemExit(main())
