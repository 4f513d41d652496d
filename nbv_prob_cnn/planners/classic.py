"""The method that needs no gain: ``random``."""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.gain import empty_origins
from nbv_prob_cnn.planners.base import PlanningContext, ViewChoice


class RandomPlanner:
    """A random orientation at a random empty cell (gain reported as NaN)."""

    name = "random"

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        origins = empty_origins(state)
        if origins.shape[0] == 0:
            return None
        cell = origins[context.rng.integers(origins.shape[0])]
        view = int(context.rng.integers(context.orientations.shape[0]))
        return ViewChoice(cell.copy(), view, float("nan"))
