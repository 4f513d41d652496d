"""A planner's completion and ranking through the servers: ``/nbv/complete`` (CompleteGrid) and
``/nbv/rank_views`` (RankViews) as the hooks of a core planner's
:class:`~nbv_prob_cnn.planners.base.PlanningContext` (``completion``, ``ranker``).
:func:`complete_via_service` alone is the completion through the service (``gain_server``'s
``completion:=service`` too).

The ranking request carries the workspace box, the origin budget and, when the arm limits the
origins (capability map, lowest view height), the allowed origins and their allowed views; a
planner's grid that differs from the message's (the arm's swept space carved free) travels as a
grid message of its own. The servers' own times of the last requests are kept for the log
(:attr:`RemotePlanning.server_times`).
"""

from __future__ import annotations

import array

import numpy as np
from geometry_msgs.msg import Point
from nbv_prob_cnn_msgs.msg import ProbabilityGrid, VoxelGrid
from nbv_prob_cnn_msgs.srv import CompleteGrid, RankViews
from rclpy.node import Node

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.planners import PlanningContext, ViewChoice
from nbv_prob_cnn.planners.base import CompletionHook, RankHook, filter_region
from nbv_prob_cnn.planners.ranked_views import ranked_from_arrays, view_mask_to_bytes
from nbv_prob_cnn.planners.recording import RecordingPlanner
from nbv_prob_cnn.planners.requests import choice_from_pose, flat_cells
from nbv_prob_cnn.planners.workspace import Box
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import grid_to_msg, msg_to_probability, pose_to_arrays, probability_to_msg
from nbv_prob_cnn.ros.runtime import call_service


def point(values: np.ndarray) -> Point:
    return Point(x=float(values[0]), y=float(values[1]), z=float(values[2]))


def complete_via_service(
    node: Node, client, grid: VoxelGrid, dataset: str, timeout_s: float, interrupt: Interrupt | None = None
) -> tuple[np.ndarray, CompleteGrid.Response]:
    """The probability map of ``grid`` by the completion network of ``dataset``, from the server
    that ``client`` (a CompleteGrid client of ``node``) calls, and the server's reply.

    Raises:
        ValueError: the server answered with an error.
        TimeoutError, WaitInterruptedError: as :func:`~nbv_prob_cnn.ros.runtime.call_service`.
    """
    call = CompleteGrid.Request(grid=grid, dataset=dataset)
    reply = call_service(node, client, call, timeout_s, interrupt)
    if not reply.success:
        raise ValueError(f"completion failed: {reply.message}")
    prob, _ = msg_to_probability(reply.probability)
    return prob, reply


class RemotePlanning:
    """The clients of the completion and ranking servers on ``node`` (see the module docstring)."""

    def __init__(self, node: Node, callback_group=None) -> None:
        self._node = node
        self._complete_client = node.create_client(CompleteGrid, names.COMPLETE, callback_group=callback_group)
        self._rank_client = node.create_client(RankViews, names.RANK_VIEWS, callback_group=callback_group)
        #: the servers' own times on the last plan's requests: cnn_server, cnn_inference, rank_server (s)
        self.server_times: dict[str, float] = {}

    def hooks(
        self,
        grid: VoxelGrid,
        original: np.ndarray,
        geometry: GridGeometry,
        context: PlanningContext,
        planner: RecordingPlanner,
        box: Box | None,
        max_origins: int,
        send_allowed: bool,
        dataset: str,
        timeout_s: float,
        interrupt: Interrupt,
    ) -> tuple[CompletionHook, RankHook]:
        """The completion and ranking hooks of one plan on ``grid`` (whose state is ``original``).

        Args:
            planner: its ``arm_filter`` and ``view_mask`` (when set) travel as allowed origins and views.
            box: the camera workspace (None: none).
            max_origins: the request's origin budget.
            send_allowed: send the arm's allowed origins (a capability map or a height limit is in use).
            dataset: of the completion network.
            timeout_s: of each service call.
        """
        completed: dict = {}
        carved: list = []  # (state, message) of the planner's grid when it differs (swept space carved)
        node = self._node

        def grid_msg(state: np.ndarray) -> VoxelGrid:
            if state.shape == original.shape and np.array_equal(state, original):
                return grid
            if not carved or carved[0][0] is not state:
                carved[:] = [(state, grid_to_msg(state, geometry, grid.header.frame_id, grid.header.stamp))]
            return carved[0][1]

        def complete(state: np.ndarray, context: PlanningContext, corner: tuple[int, ...] | None = None) -> np.ndarray:
            if corner is None:
                message = grid_msg(state)
            else:  # the CNN window: that part of the grid alone
                message = grid_to_msg(state, geometry.window(corner, state.shape), grid.header.frame_id,
                                      grid.header.stamp)  # fmt: skip
            prob, reply = complete_via_service(node, self._complete_client, message, dataset, timeout_s, interrupt)
            if corner is None:  # the whole grid's map: the ranking request can carry the reply's message
                completed["msg"], completed["prob"] = reply.probability, prob
            self.server_times.update(cnn_server=reply.time_total_s, cnn_inference=reply.inference_time_s)
            return prob

        def probability_msg(prob: np.ndarray) -> ProbabilityGrid:
            if prob is completed.get("prob"):
                return completed["msg"]
            return probability_to_msg(prob, geometry, grid.header.frame_id, grid.header.stamp)

        def rank(method: str, state: np.ndarray, prob: np.ndarray | None, top_k: int) -> list[ViewChoice]:
            call = RankViews.Request(
                grid=grid_msg(state), method=method, top_k=top_k, use_workspace=box is not None, compact=True
            )
            if box is not None:
                call.workspace_min, call.workspace_max = point(box[0]), point(box[1])
            call.max_origins = max_origins
            if planner.arm_filter is not None and send_allowed:
                # the workspace's cells alone: gain_server keeps only allowed origins in the workspace
                allowed_cells = planner.arm_filter(
                    context.candidate_origins(state, filter_region(planner.request_filter))
                )
                allowed = flat_cells(allowed_cells, state.shape)
                call.allowed_origins = array.array("I", allowed.astype(np.uint32).tobytes())
                if planner.view_mask is not None:  # the capability map's orientations, never a taken view
                    mask = view_mask_to_bytes(allowed, planner.view_mask(allowed_cells))
                    call.allowed_views = array.array("B", mask)
            if prob is not None:
                call.probability = probability_msg(prob)
            reply = call_service(node, self._rank_client, call, timeout_s, interrupt)
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
