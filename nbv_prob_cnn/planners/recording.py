"""A planner wrapper for a planning request (no ROS here): the request's origin filter applied
after the arm's capability filter, and the ranked list kept for the reply and the markers."""

from __future__ import annotations

import time

import numpy as np

from nbv_prob_cnn.arm.feasibility import takes_view_mask
from nbv_prob_cnn.planners.base import (
    OriginFilter,
    Planner,
    PlanningContext,
    ViewChoice,
    ViewMask,
    bounded,
    filter_region,
)

#: The times :attr:`RecordingPlanner.stage_seconds` sums over its ranks.
RANK_STAGES = ("rank", "cnn", "raycast", "views")


class RecordingPlanner:
    """A planner whose ``rank`` also applies the request's origin filter (after the arm's
    capability filter, kept as ``arm_filter`` for the ranking server) and keeps the ranked list
    (markers, ``ranked`` of the response).

    Args:
        planner: the method.
        request_filter: the request's origin filter (workspace, origin budget).
        arm_limit: applied before the arm's capability filter (e.g. a lowest camera height); None: none.
    """

    def __init__(self, planner: Planner, request_filter: OriginFilter, arm_limit: OriginFilter | None = None) -> None:
        self.planner, self.request_filter, self.arm_limit = planner, request_filter, arm_limit
        self.name = planner.name
        self.ranked: list[ViewChoice] = []
        self.arm_filter: OriginFilter | None = None
        self.view_mask: ViewMask | None = None
        self.seconds = 0.0  # the last rank's time (CNN included)
        #: every rank so far, summed (s): ``rank`` (the calls, CNN included) and the best view's
        #: ``cnn``, ``raycast`` and ``views`` of each (a plan with the arm's near-camera fallback ranks twice)
        self.stage_seconds = dict.fromkeys(RANK_STAGES, 0.0)
        self.takes_view_mask = takes_view_mask(planner)  # passed on to the planner (plan_with_arm)

    def rank(
        self,
        state: np.ndarray,
        context: PlanningContext,
        top_k: int = 1,
        origin_filter: OriginFilter | None = None,
        view_mask: ViewMask | None = None,
    ) -> list[ViewChoice]:
        keep, capability, limit = self.request_filter, origin_filter, self.arm_limit

        def arm_filter(origins: np.ndarray) -> np.ndarray:
            assert capability is not None
            return capability(origins if limit is None else limit(origins))

        def both(origins: np.ndarray) -> np.ndarray:
            return keep(origins if capability is None else arm_filter(origins))

        searched = bounded(filter_region(keep), both)  # every origin ``both`` keeps passed ``keep``
        self.arm_filter = None if capability is None else arm_filter
        self.view_mask = view_mask  # a remote ranking gets it as allowed_views
        start = time.perf_counter()
        if view_mask is None:
            self.ranked = self.planner.rank(state, context, top_k, searched)
        else:
            self.ranked = self.planner.rank(state, context, top_k, searched, view_mask=view_mask)  # type: ignore[call-arg]
        self.seconds = time.perf_counter() - start
        self.stage_seconds["rank"] += self.seconds
        if self.ranked:
            for stage in ("cnn", "raycast", "views"):
                self.stage_seconds[stage] += float(self.ranked[0].times.get(stage, 0.0))
        return self.ranked

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        found = self.rank(state, context)
        return found[0] if found else None
