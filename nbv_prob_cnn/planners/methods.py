"""The gain-based methods of SPEC §6 as data, and the one planner that runs them all.

Every gain-based method is the same kernel with a different probability map (and origin set):

=============  ======  =====================================  ===========================
method         gain    occupancy probability of unknown cells  candidate origins
=============  ======  =====================================  ===========================
``ig``         ``ig``  — (rays stop at the first non-empty)    all (3DT: stride 2)
``prob_ig``    prob    constant ``P0``                         all
``cnn_prob``   prob    completion CNN                          all
``cnn_prob_d`` prob    completion CNN                          random 2000 (2D) / 500 (3D)
``omniscient`` prob    ground truth                            all
=============  ======  =====================================  ===========================
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.grid import probability_from_truth, probability_with_constant
from nbv_prob_cnn.modes import GainMode, ProbabilitySource
from nbv_prob_cnn.planners.base import PlanningContext, ViewChoice, search_views

#: Origins evaluated by the downsampled method, per dimensionality (SPEC §5).
DOWNSAMPLED_ORIGINS = {2: 2000, 3: 500}


@dataclass(frozen=True)
class GainMethod:
    """How a gain-based method builds its probability map and picks its origins."""

    name: str
    mode: GainMode  # "prob" or "ig"
    probability: ProbabilitySource | None  # "constant", "cnn", "oracle" or None (ig)
    downsampled: bool = False


GAIN_METHODS: dict[str, GainMethod] = {
    m.name: m
    for m in (
        GainMethod("ig", "ig", None),
        GainMethod("prob_ig", "prob", "constant"),
        GainMethod("cnn_prob", "prob", "cnn"),
        GainMethod("cnn_prob_d", "prob", "cnn", downsampled=True),
        GainMethod("omniscient", "prob", "oracle"),
    )
}


def cnn_completion(state: np.ndarray, context: PlanningContext) -> np.ndarray:
    """The completion CNN of the context's data set, in this process (shipped weights)."""
    from nbv_prob_cnn.completion import complete

    return complete(state, dataset=context.defaults.name)


def probability_map(
    method: GainMethod,
    state: np.ndarray,
    context: PlanningContext,
    completion: Callable[[np.ndarray, PlanningContext], np.ndarray] = cnn_completion,
) -> np.ndarray | None:
    """The probabilistic map ``P`` the method ray-casts on (None for ``ig``)."""
    if method.probability is None:
        return None
    if method.probability == "constant":
        return probability_with_constant(state, context.defaults.p0)
    if method.probability == "oracle":
        if context.ground_truth is None:
            raise ValueError(f"{method.name}: needs the ground truth (context.ground_truth)")
        return probability_from_truth(state, context.ground_truth)
    return completion(state, context)


def method_origins(method: GainMethod, state: np.ndarray, context: PlanningContext) -> np.ndarray:
    """Candidate origins of the method: the context's, or a random fixed-size subset."""
    origins = context.candidate_origins(state)
    count = DOWNSAMPLED_ORIGINS[state.ndim]
    if method.downsampled and origins.shape[0] > count:
        keep = np.sort(context.rng.choice(origins.shape[0], size=count, replace=False))
        origins = origins[keep]
    return origins


class GainPlanner:
    """Any gain-based method: probability map (timed as ``cnn``), then the view search."""

    def __init__(
        self,
        method: GainMethod,
        completion: Callable[[np.ndarray, PlanningContext], np.ndarray] = cnn_completion,
    ) -> None:
        self.method = method
        self.name = method.name
        self._completion = completion

    def rank(
        self,
        state: np.ndarray,
        context: PlanningContext,
        top_k: int = 1,
        origin_filter: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> list[ViewChoice]:
        """The ``top_k`` best views, best first (empty if no view has positive gain).

        ``origin_filter`` may narrow the method's candidate origins (e.g. to a reachable box).
        """
        start = time.perf_counter()
        prob = probability_map(self.method, state, context, self._completion)
        t_prob = time.perf_counter() - start
        origins = method_origins(self.method, state, context)
        if origin_filter is not None:
            origins = origin_filter(origins)
        found = search_views(state, prob, origins, context, self.method.mode, top_k)
        for choice in found:
            choice.times["cnn"] = t_prob if self.method.probability == "cnn" else 0.0
        return found

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        found = self.rank(state, context)
        return found[0] if found else None
