"""The parts of ``nbv_planner``'s Explore action around the core's
:class:`~nbv_prob_cnn.exploration.session.ExplorationSession` (the movers are in
:mod:`~nbv_prob_cnn.ros.movers`): the integrator's grid as grid source, the node's plan on the
goal's request as view planner, and the goal's state once a cancel was accepted."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from geometry_msgs.msg import Point
from nbv_prob_cnn_msgs.action import Explore
from nbv_prob_cnn_msgs.srv import PlanNextBestView

from nbv_prob_cnn.arm.arm_session import NO_REACHABLE_VIEW
from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.session import NoView
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.planners import ViewChoice
from nbv_prob_cnn.planners.workspace import UNBOUNDED
from nbv_prob_cnn.ros.conversions import msg_to_grid
from nbv_prob_cnn.ros.grid_holder import LatestGrid
from nbv_prob_cnn.ros.movers import PlannedResponse
from nbv_prob_cnn.ros.robot_params import JointStateTracker

#: Planning's message when every candidate view has zero gain (a normal end of an exploration).
NO_POSITIVE_GAIN = "no view with positive gain"

#: ``plan(request, interrupt, guard) -> (response, chosen view)``: a node's planning, never raising.
PlanFunction = Callable[
    [PlanNextBestView.Request, Interrupt, ViewGuard | None], tuple[PlanNextBestView.Response, ViewChoice | None]
]


class ExploreGrids:
    """The grid source of an exploration: the integrator's grid, the next one that includes a
    frame taken at the new pose (TimeoutError after ``timeout_s``)."""

    def __init__(self, grids: LatestGrid, timeout_s: float) -> None:
        self.grids, self.timeout_s = grids, timeout_s

    def first_grid(self, interrupt: Interrupt) -> np.ndarray:
        return self.grid_after(0, interrupt)

    def grid_after(self, stamp_ns: int, interrupt: Interrupt) -> np.ndarray:
        return msg_to_grid(self.grids.wait_for_stamp(stamp_ns, self.timeout_s, interrupt))[0]


class GoalPlanner:
    """The view planner of an Explore goal: ``plan`` (the node's) with the goal's method and
    workspace, after the arm's first joint state (``joints``, waited for up to ``joints_timeout_s``);
    no positive gain or no view the arm reaches is the end of the exploration, any other planning
    failure an error."""

    def __init__(
        self,
        plan: PlanFunction,
        joints: JointStateTracker | None,
        joints_timeout_s: float,
        goal: Explore.Goal,
        estimate_surface: bool = False,
    ) -> None:
        self._plan, self._joints, self._joints_timeout_s = plan, joints, joints_timeout_s
        self.request = goal_plan_request(goal)
        self.estimate_surface = estimate_surface  # the stop rule's estimate: a second view search per view

    def plan(
        self, grid: np.ndarray, views: int, guard: ViewGuard | None, interrupt: Interrupt
    ) -> PlannedResponse | NoView:
        if self._joints is not None:  # the arm's first joint state may still be on its way
            self._joints.wait_for_first(self._joints_timeout_s, interrupt)
        planned, chosen = self._plan(self.request, interrupt, guard)
        interrupt.check()  # a plan interrupted while it waited for a server answers an error
        if planned.success:
            estimate = getattr(chosen, "surface_estimate", None) if self.estimate_surface else None
            new_surface = estimate() if estimate is not None else None  # the stop rule's (docs/method.md)
            return PlannedResponse(planned, planned.best_gain, chosen, planned.time_total_s, new_surface)
        if planned.message.startswith(NO_POSITIVE_GAIN) or planned.message.startswith(NO_REACHABLE_VIEW):
            return NoView(planned.message)
        raise ValueError(f"planning failed: {planned.message}")


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


def cancel_requested(goal_handle, timeout_s: float) -> bool:
    """Whether the goal is CANCELING, waiting up to ``timeout_s`` for rclpy to mark it (it does so
    right after the cancel callback that woke the exploration returned)."""
    deadline = time.monotonic() + timeout_s
    while not goal_handle.is_cancel_requested:
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.002)
    return True
