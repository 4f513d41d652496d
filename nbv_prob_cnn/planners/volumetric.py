"""The field's volumetric gains as planners (docs/method.md#volumetric-baselines): ``occlusion_aware``,
``unobserved_voxel``, ``rear_side_voxel``, ``proximity_count``, ``average_entropy``
(:mod:`nbv_prob_cnn.gain.volumetric`), on OctoMap's probabilities of the ternary grid (the prior in
unknown cells, as the OctoMap implementations they come from), from a random subset of the
candidate origins of the downsampled method's size (the numpy ray march of every empty cell would
cost minutes a view). ``rear_side_voxel``, ``proximity_count`` and ``average_entropy`` score nothing while no surface is
known (a first view that saw none): then, and only then, ``unobserved_voxel`` ranks the views, and
the choice's gain is that one's (never a silent stop after one view)."""

from __future__ import annotations

import time

import numpy as np

from nbv_prob_cnn.gain.volumetric import volumetric_view_gains
from nbv_prob_cnn.planners.base import OriginFilter, PlanningContext, RankingPlanner, ViewChoice
from nbv_prob_cnn.planners.candidates import near_unknown_origins, ray_reach
from nbv_prob_cnn.planners.methods import GainMethod, method_origins

#: The formulations that score nothing while no surface is known.
NEEDS_A_SURFACE = ("rear_side_voxel", "proximity_count", "average_entropy")


def _view_gains(state: np.ndarray, context: PlanningContext, origins: np.ndarray, formulation: str) -> np.ndarray:
    sensor = context.active_sensor
    return volumetric_view_gains(state, None, context.directions, sensor.r_max, context.membership, origins,
                                 formulation).ravel()  # fmt: skip


class VolumetricPlanner(RankingPlanner):
    """The best views of one volumetric formulation (ties: the first origin, then the first view)."""

    def __init__(self, formulation: str) -> None:
        self.name = formulation
        self._origins = GainMethod(formulation, "prob", None, downsampled=True)  # the origin draw of cnn_prob_d

    def rank_here(
        self, state: np.ndarray, context: PlanningContext, top_k: int, origin_filter: OriginFilter | None
    ) -> list[ViewChoice]:
        origins = method_origins(self._origins, state, context, origin_filter)
        origins = near_unknown_origins(state, origins, ray_reach(context.active_sensor.r_max))
        if origins.shape[0] == 0:
            return []
        start = time.perf_counter()
        gains = _view_gains(state, context, origins, self.name)
        if self.name in NEEDS_A_SURFACE and not np.any(gains > 0.0):
            gains = _view_gains(state, context, origins, "unobserved_voxel")
        seconds = time.perf_counter() - start
        order = np.lexsort((np.arange(gains.size), -gains))[: max(1, top_k)]
        n_views = context.membership.shape[1]
        return [
            ViewChoice(
                origins[i // n_views].copy(),
                int(i % n_views),
                float(gains[i]),
                {"cnn": 0.0, "raycast": seconds, "views": 0.0},
            )  # fmt: skip
            for i in order
            if gains[i] > 0.0
        ]
