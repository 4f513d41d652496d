"""The method that needs no gain: ``random``."""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.gain import empty_origins
from nbv_prob_cnn.planners.base import OriginFilter, PlanningContext, RankingPlanner, ViewChoice, filter_region


class RandomPlanner(RankingPlanner):
    """A random orientation at a random empty cell (gain reported as NaN); ``top_k`` such views."""

    name = "random"

    def rank_here(
        self, state: np.ndarray, context: PlanningContext, top_k: int, origin_filter: OriginFilter | None
    ) -> list[ViewChoice]:
        origins = empty_origins(state, region=filter_region(origin_filter))
        if origin_filter is not None:
            origins = origin_filter(origins)
        if origins.shape[0] == 0:
            return []
        choices = []
        for _ in range(max(1, top_k)):
            cell = origins[context.rng.integers(origins.shape[0])]
            view = int(context.rng.integers(context.orientations.shape[0]))
            choices.append(ViewChoice(cell.copy(), view, float("nan")))
        return choices
