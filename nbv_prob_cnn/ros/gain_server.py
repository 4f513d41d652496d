"""Node ``gain_server``: scores camera poses (``/nbv/evaluate_views``) and searches the best
views over candidate origins (``/nbv/rank_views``) with the OpenCL ray-casting kernel.

The CNN methods get their probability map from the completion server (``/nbv/complete``) or,
with ``completion:=in_process``, from the CNN loaded in this process. The default method is
:data:`~nbv_prob_cnn.planners.registry.DEFAULT_METHOD` (``cnn_surface``), as ``nbv_planner``'s.

Poses given in another frame than the grid's are transformed into it by TF (``/tf`` +
``/tf_static``, :class:`~nbv_prob_cnn.ros.tf_listener.TfListener`) at their stamp (0: the newest
transform); a pose TF cannot transform is invalid, its reason naming the missing frame or the
time gap. The planning frustum comes from the depth camera's CameraInfo and the range
parameters (:class:`~nbv_prob_cnn.ros.camera_sensor.CameraInfoSensor`).

``/nbv/evaluate_views`` sums, per pose, ``evaluate_rays_across`` (32) rays across the pose's own image,
weighted by their solid angles (docs/method.md#scoring-given-poses): it ranks recorded Kinect poses far
better than the view search's 56 rays, of which 2 to 6 fall in the frustum (``nbv gain-study``). With
``evaluate_rays_across:=0`` a pose gets the gain ``/nbv/rank_views`` gives it.

With ``use_arm:=true`` (robot description parameters of :class:`RobotParams`) ``/nbv/evaluate_views``
also reports per pose whether the arm reaches it: an IK solution (seeded from the latest
``/joint_states``, or the reference configuration before any) free of self-collision and of the
grid's occupied and unknown cells (:func:`~nbv_prob_cnn.arm.views.reachable_poses`; no path check).
"""

from __future__ import annotations

import array
import time
from dataclasses import dataclass

import numpy as np
from nbv_prob_cnn_msgs.msg import ViewScore
from nbv_prob_cnn_msgs.srv import CompleteGrid, EvaluateViews, RankViews
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState

from nbv_prob_cnn.arm.views import ArmPlanningSetup, reachable_poses
from nbv_prob_cnn.basics.camera import DATASETS, quaternion_from_matrix
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.modes import Backend
from nbv_prob_cnn.gain.sampling import SAMPLINGS
from nbv_prob_cnn.perception.messages import stamp_ns
from nbv_prob_cnn.perception.tf_buffer import TransformError, matrix_from_translation_quaternion
from nbv_prob_cnn.planners import PlanningContext, check_ros_method
from nbv_prob_cnn.planners.base import bounded, filter_region
from nbv_prob_cnn.planners.methods import cnn_completion, probability_map
from nbv_prob_cnn.planners.pose_scoring import EVALUATE_RAYS_ACROSS, INVALID_POSE, score_poses
from nbv_prob_cnn.planners.ranked_views import ranked_to_arrays, view_mask_from_bytes
from nbv_prob_cnn.planners.registry import DEFAULT_METHOD
from nbv_prob_cnn.planners.requests import (
    allowed_origins_filter,
    gain_method,
    origin_filter,
    rank_for_request,
)
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.camera_sensor import CameraInfoSensor, SensorParams, node_planning_context
from nbv_prob_cnn.ros.conversions import (
    arrays_to_pose_stamped,
    grid_to_msg,
    msg_to_grid,
    msg_to_probability,
)
from nbv_prob_cnn.ros.gain_params import (
    backend_param,
    gain_variant_param,
    image_rerank_param,
    n_rays_param,
    surface_blend_param,
)
from nbv_prob_cnn.ros.grid_holder import GridSourceParams, LatestGrid, grid_transport_param
from nbv_prob_cnn.ros.joint_state_intake import JointStateIntake
from nbv_prob_cnn.ros.parameters import declare_config, param, positive_seconds
from nbv_prob_cnn.ros.remote_planning import complete_via_service
from nbv_prob_cnn.ros.robot_params import ArmViewParams, joint_state_msg
from nbv_prob_cnn.ros.runtime import run_node
from nbv_prob_cnn.ros.stream_node import StreamNode
from nbv_prob_cnn.ros.tf_listener import TfListener

MAX_POSES = 100_000


@dataclass
class GainServerConfig(GridSourceParams, SensorParams, ArmViewParams):
    """Parameters of ``gain_server`` (``method`` and ``completion_timeout_s`` may change at run time):
    where grids come from (:class:`GridSourceParams`), the robot description and ``use_arm``
    (:class:`ArmViewParams`), the planning frustum (:class:`SensorParams`), then these."""

    dataset: str = param("3dt", "sensor/ray defaults and CNN weights", choices=tuple(sorted(DATASETS)))
    method: str = param(DEFAULT_METHOD, "method when a request names none", dynamic=True, check=check_ros_method)
    backend: Backend = backend_param("ray-casting backend")
    n_rays: int = n_rays_param("ray sub-cells per side (0 = data set default)")
    gain_variant: str = gain_variant_param(
        "gain: 'paper' (docs/method.md) or 'original' (the authors' host choices, docs/original_code.md)"
    )
    surface_blend: float = surface_blend_param(
        "the surface methods' blend (cnn_surface, prob_surface): 0 the paper's gain, 1 the surface alone"
    )
    image_rerank: int = image_rerank_param(
        "the surface methods re-rank the view search's best this many views by rays through each view's own "
        "image (0: no re-ranking; about 0.15 s a plan on the 3DT grid)"
    )
    completion: str = param(
        "service", "CNN maps from the completion service or in this process", choices=("service", "in_process"),
    )  # fmt: skip
    completion_timeout_s: float = param(
        60.0, "wait for nbv/complete", min_value=0.1, max_value=600.0, dynamic=True, check=positive_seconds
    )
    frame_id: str = param("world", "frame of the grid when the grid message has none")
    grid_transport: str = grid_transport_param()
    evaluate_rays_across: int = param(
        EVALUATE_RAYS_ACROSS, "evaluate_views: rays across each pose's own image, its gain in steradians (0 = the "
        "view search's rays inside the pose's frustum, n_rays: the gain /nbv/rank_views gives that pose)",
        min_value=0, max_value=256,
    )  # fmt: skip
    evaluate_sampling: str = param("rounded", "evaluate_views: gain sampling, 'rounded' or 'exact' (docs/sensing.md)",
                                   choices=SAMPLINGS)  # fmt: skip

    def apply_pose_scoring(self, context: PlanningContext) -> None:
        """Set ``context``'s pose-scoring settings (``evaluate_views``) from these parameters."""
        context.sampling = self.evaluate_sampling


class GainServer(Node):
    """Serves view gains on the latest grid (or on the grid sent with the request)."""

    def __init__(self) -> None:
        super().__init__("gain_server")
        self.config = cfg = declare_config(self, GainServerConfig, mirror=False)
        self._rng = np.random.default_rng()
        group = ReentrantCallbackGroup()
        self._arm: ArmPlanningSetup | None = None
        self._joints: JointStateIntake | None = None
        if cfg.use_arm:
            # no capability map: every pose gets the exact check
            robot = cfg.robot_config(self)
            self._arm = ArmPlanningSetup(robot, free_above_m=cfg.free_above(), capability_stride=0)
        # joint_states and /tf come at the robot's rate: on a side node with its own thread (stream_node)
        self._streams = StreamNode(self)
        if self._arm is not None:
            self._joints = JointStateIntake(self._arm.robot, self, self._streams.node)
        self._grid = LatestGrid(self, callback_group=group, transport=cfg.grid_transport, source=cfg)
        self._tf = TfListener(self._streams.node)
        self._sensor = CameraInfoSensor(self, cfg, cfg.dataset, callback_group=group)
        self._complete_client = self.create_client(CompleteGrid, names.COMPLETE, callback_group=group)
        # one request at a time: a request may wait for /nbv/complete, whose answer another thread of the
        # executor (4) must take; requests in parallel could hold every thread (see nbv_planner)
        requests = MutuallyExclusiveCallbackGroup()
        self.create_service(EvaluateViews, names.EVALUATE_VIEWS, self._evaluate_views, callback_group=requests)
        self.create_service(RankViews, names.RANK_VIEWS, self._rank_views, callback_group=requests)
        warm = self._warm_up_ray_caster()
        self.get_logger().info(
            f"gain_server ready: dataset {cfg.dataset}, method {cfg.method}, TF by {self._tf.backend}{warm}"
        )

    def _warm_up_ray_caster(self) -> str:
        """Build the OpenCL kernels now (about 1.5 s), not in the first request; "" without OpenCL."""
        from nbv_prob_cnn.basics.cl_device import opencl_available

        if self.config.backend == "numpy" or not opencl_available():
            return ""
        from nbv_prob_cnn.gain.opencl import get_ray_caster

        start = time.perf_counter()
        get_ray_caster()
        return f", OpenCL kernels built in {time.perf_counter() - start:.1f} s"

    def _arm_solutions(self, state, geometry, positions: np.ndarray, quats: np.ndarray) -> list[JointState]:
        """Per pose the IK solution as a JointState (empty when the arm cannot take the pose)."""
        assert self._arm is not None and self._joints is not None  # use_arm
        seed = self._joints.current_or(self._arm.robot.reference_q)  # raises on wrong names
        solutions = reachable_poses(self._arm.feasibility(geometry), positions, quats, state, geometry, seed)
        return [joint_state_msg(self._arm.robot, q) for q in solutions]

    def _completion(self, header, geometry: GridGeometry):
        """The CNN probability source for this node's mode."""
        if self.config.completion == "in_process":
            return cnn_completion

        def via_service(
            state: np.ndarray, context: PlanningContext, corner: tuple[int, ...] | None = None
        ) -> np.ndarray:
            part = geometry if corner is None else geometry.window(corner, state.shape)
            grid = grid_to_msg(state, part, header.frame_id or self.config.frame_id, header.stamp)
            timeout_s = self.config.completion_timeout_s
            prob, _ = complete_via_service(self, self._complete_client, grid, self.config.dataset, timeout_s)
            return prob

        return via_service

    def _evaluate_views(self, request: EvaluateViews.Request, response: EvaluateViews.Response):
        start = time.perf_counter()
        try:
            if len(request.poses) == 0:
                raise ValueError("no poses in the request")
            if len(request.poses) > MAX_POSES:
                raise ValueError(f"{len(request.poses)} poses exceed the limit of {MAX_POSES}")
            grid = self._grid.latest()
            state, geometry = msg_to_grid(grid)
            frame = grid.header.frame_id or self.config.frame_id
            method = gain_method(request.method, self.config.method)
            frustum = self._sensor.frustum(request.hfov_deg, request.vfov_deg, request.max_range_m)
            context = node_planning_context(self.config, geometry, frustum, self._rng)
            self.config.apply_pose_scoring(context)
            positions = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in request.poses])
            o = [p.pose.orientation for p in request.poses]
            quats = np.array([[q.x, q.y, q.z, q.w] for q in o])
            frame_errors = self._poses_into_grid_frame(request.poses, frame, positions, quats)
            context.completion = self._completion(grid.header, geometry)
            prob = probability_map(method, state, context)
            scores = score_poses(state, prob, geometry, positions, quats, context, method.mode,
                                 score_unknown_cells=request.score_unknown_cells,
                                 rays_across=self.config.evaluate_rays_across, surface=method.surface)  # fmt: skip
            reasons = list(scores.reasons)
            for i, error in frame_errors.items():
                scores.validity[i] = INVALID_POSE
                scores.gains[i] = 0.0
                reasons[i] = (
                    f"pose in frame {request.poses[i].header.frame_id!r}, which TF cannot transform into the "
                    f"grid frame {frame!r}: {error}"
                )
            response.gains = array.array("f", scores.gains.astype(np.float32).tobytes())
            response.validity = array.array("B", scores.validity.astype(np.uint8).tobytes())
            response.reasons = reasons
            response.success = True
            response.message = f"{int(np.count_nonzero(scores.validity == 0))} of {len(reasons)} poses valid"
            if self._arm is not None:
                response.ik_solutions = self._arm_solutions(state, geometry, positions, quats)
                response.reachable = [bool(s.name) for s in response.ik_solutions]
                response.message += f", {sum(response.reachable)} reachable by the arm"
        except (ValueError, TimeoutError, RuntimeError) as exc:
            response.success = False
            response.message = str(exc)
            # an error reply never marks a pose valid (the scores may have been filled before the error)
            count = len(request.poses)
            response.gains = array.array("f", bytes(4 * count))
            response.validity = array.array("B", [INVALID_POSE] * count)
            response.reasons = [f"error: {exc}"] * count
            response.ik_solutions, response.reachable = [], []
            self.get_logger().warning(f"evaluate_views: {exc}")
        response.computation_time_s = time.perf_counter() - start
        return response

    def _poses_into_grid_frame(self, poses, frame: str, positions: np.ndarray, quats: np.ndarray) -> dict[int, str]:
        """Transform (in place) the poses given in another frame than the grid's ``frame`` by TF,
        each at its stamp (0: the newest transform). Returns, per pose TF cannot transform, why
        (its position is then NaN, so it is scored as invalid)."""
        errors: dict[int, str] = {}
        for i, pose in enumerate(poses):
            source = pose.header.frame_id.lstrip("/")
            if not source or source == frame.lstrip("/"):
                continue
            try:
                stamp = stamp_ns(pose.header.stamp) or None
                grid_from_source, _ = self._tf.lookup(frame, source, stamp)
                pose_matrix = matrix_from_translation_quaternion(positions[i], quats[i])
            except (TransformError, ValueError) as exc:
                errors[i] = str(exc)
                positions[i] = np.nan
                continue
            moved = grid_from_source @ pose_matrix
            positions[i] = moved[:3, 3]
            quats[i] = quaternion_from_matrix(moved[:3, :3])
        return errors

    def _rank_views(self, request: RankViews.Request, response: RankViews.Response):
        start = time.perf_counter()
        try:
            grid = request.grid if request.grid.size_x else self._grid.latest()
            state, geometry = msg_to_grid(grid)
            frame = grid.header.frame_id or self.config.frame_id
            context = node_planning_context(self.config, geometry, self._sensor.frustum(), self._rng)
            given = None
            if request.probability.size_x:
                given, _ = msg_to_probability(request.probability)
            elif request.method == "prob":
                raise ValueError("method 'prob' needs a probability grid")
            context.completion = self._completion(grid.header, geometry)
            keep = origin_filter(
                geometry, request.use_workspace,
                np.array([request.workspace_min.x, request.workspace_min.y, request.workspace_min.z]),
                np.array([request.workspace_max.x, request.workspace_max.y, request.workspace_max.z]),
                int(request.max_origins), self._rng,
            )  # fmt: skip
            allowed_flat = np.frombuffer(request.allowed_origins, dtype=np.uint32)
            allowed = allowed_origins_filter(allowed_flat, state.shape) if allowed_flat.size else None
            view_mask = None
            if len(request.allowed_views):
                if not allowed_flat.size:
                    raise ValueError("allowed_views needs allowed_origins (one row of orientations per allowed origin)")
                n_views = len(context.orientations)
                view_mask = view_mask_from_bytes(allowed_flat, bytes(request.allowed_views), state.shape, n_views)
            evaluated = []

            def counting(origins):
                kept = keep(origins if allowed is None else allowed(origins))
                evaluated.append(kept.shape[0])
                return kept

            searched = bounded(filter_region(keep), counting)  # candidates listed in the workspace's cells alone
            ranked = rank_for_request(
                request.method, self.config.method, state, context, request.top_k, searched, given, view_mask
            )
            arrays = ranked_to_arrays(ranked, context, geometry)
            response.ranked_cells = array.array("I", arrays.cells.astype(np.uint32).tobytes())
            response.ranked_orientations = array.array("H", arrays.orientations.astype(np.uint16).tobytes())
            response.ranked_positions = array.array("d", arrays.positions.astype(np.float64).tobytes())
            response.ranked_quaternions = array.array("d", arrays.quaternions.astype(np.float64).tobytes())
            response.ranked_gains = array.array("f", arrays.gains.astype(np.float32).tobytes())
            if not request.compact:
                response.ranked = [
                    ViewScore(pose=arrays_to_pose_stamped(p, q, frame), gain=float(g))
                    for p, q, g in zip(arrays.positions, arrays.quaternions, arrays.gains.tolist(), strict=True)
                ]
            response.evaluated_origins = int(evaluated[0]) if evaluated else 0
            if ranked:
                response.time_raycast_s = ranked[0].times["raycast"]
                response.time_views_s = ranked[0].times["views"]
            response.success = True
            response.message = "" if ranked else "no view with positive gain"
            self.get_logger().info(
                f"rank_views: {request.method or self.config.method}, {response.evaluated_origins} origins, "
                f"{len(ranked)} views in {time.perf_counter() - start:.2f} s"
            )
        except (ValueError, TimeoutError, RuntimeError) as exc:
            response.success = False
            response.message = str(exc)
            self.get_logger().warning(f"rank_views: {exc}")
        response.time_total_s = time.perf_counter() - start
        return response

    def destroy_node(self) -> None:
        self._streams.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(GainServer, args)


if __name__ == "__main__":
    raise SystemExit(main())
