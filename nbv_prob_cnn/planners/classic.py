"""The methods without a neural network: ``random``, ``ig``, ``prob_ig``, ``omniscient``."""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.gain import empty_origins
from nbv_prob_cnn.grid import probability_from_truth, probability_with_constant
from nbv_prob_cnn.planners.base import PlanningContext, ViewChoice, search_best_view


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


class InformationGainPlanner:
    """Non-probabilistic information gain: rays stop at the first non-empty cell."""

    name = "ig"

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        return search_best_view(state, None, context.candidate_origins(state), context, mode="ig")


class ProbabilisticPlanner:
    """Probabilistic gain on a map built by ``probability(state, context)``."""

    def __init__(self, name: str, probability) -> None:
        self.name = name
        self._probability = probability

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        prob = self._probability(state, context)
        return search_best_view(state, prob, context.candidate_origins(state), context)


def constant_probability(state: np.ndarray, context: PlanningContext) -> np.ndarray:
    """Prob. IG: ``P0`` in every unknown cell."""
    return probability_with_constant(state, context.defaults.p0)


def oracle_probability(state: np.ndarray, context: PlanningContext) -> np.ndarray:
    """Omniscient: the ground truth in unknown cells."""
    if context.ground_truth is None:
        raise ValueError("omniscient: needs the ground truth (context.ground_truth)")
    return probability_from_truth(state, context.ground_truth)
