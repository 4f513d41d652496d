"""The gain-based methods of docs/method.md#methods as data, and the one planner that runs them all.

Every gain-based method is the same kernel with a different probability map (and origin set):

=============  ======  =====================================  ===========================
method         gain    occupancy probability of unknown cells  candidate origins
=============  ======  =====================================  ===========================
``ig``         ``ig``  — (rays stop at the first non-empty)    all (3DT: stride 2)
``prob_ig``    prob    constant ``P0``                         all
``cnn_prob``   prob    completion CNN                          all
``cnn_prob_d`` prob    completion CNN                          random 2000 (2D) / 500 (3D) [*]
``omniscient`` prob    ground truth                            all
=============  ======  =====================================  ===========================

The surface methods (docs/method.md#surface-gain) count where a ray's return is expected to land
among the unknown cells (blended with the paper's gain by ``context.surface_blend``):
``cnn_surface`` on the CNN's map, ``prob_surface`` on the constant ``P0`` (with a constant map the
surface term is ``P0`` times the paper's, so it ranks as ``prob_ig`` does: the control that shows
what the CNN's map adds) and ``omniscient_surface`` on the ground truth (simulation only). They
re-rank the search's best ``context.image_rerank`` views by rays through each view's own image
(:mod:`~nbv_prob_cnn.planners.image_rays`); with that, ``prob_surface`` no longer ranks exactly as
``prob_ig``.

[*] drawn after any origin filter (workspace box, origin budget), so that a filtered request
still evaluates up to the full budget inside the box.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.basics.grid import probability_from_truth, probability_with_constant
from nbv_prob_cnn.basics.modes import GainMode, ProbabilitySource
from nbv_prob_cnn.planners.base import (
    OriginFilter,
    PlanningContext,
    RankingPlanner,
    ViewChoice,
    ViewMask,
    filtered_origins,
    search_views,
)
from nbv_prob_cnn.planners.candidates import near_unknown_origins, ray_reach
from nbv_prob_cnn.planners.image_rays import rerank_by_image
from nbv_prob_cnn.planners.surface_stop import best_new_surface

#: Origins evaluated by the downsampled method, per dimensionality (docs/method.md#candidate-views-and-view-gain).
DOWNSAMPLED_ORIGINS = {2: 2000, 3: 500}


@dataclass(frozen=True)
class GainMethod:
    """How a gain-based method builds its probability map and picks its origins."""

    name: str
    mode: GainMode  # "prob" or "ig"
    probability: ProbabilitySource | None  # "constant", "cnn", "oracle" or None (ig)
    downsampled: bool = False
    surface: bool = False  # the surface gain (docs/method.md#surface-gain), blended by context.surface_blend


GAIN_METHODS: dict[str, GainMethod] = {
    m.name: m
    for m in (
        GainMethod("ig", "ig", None),
        GainMethod("prob_ig", "prob", "constant"),
        GainMethod("cnn_prob", "prob", "cnn"),
        GainMethod("cnn_prob_d", "prob", "cnn", downsampled=True),
        GainMethod("omniscient", "prob", "oracle"),
        GainMethod("cnn_surface", "prob", "cnn", surface=True),
        GainMethod("prob_surface", "prob", "constant", surface=True),
        GainMethod("omniscient_surface", "prob", "oracle", surface=True),
    )
}


def cnn_completion(state: np.ndarray, context: PlanningContext, corner: tuple[int, ...] | None = None) -> np.ndarray:
    """The completion CNN of the context's data set, in this process (shipped weights
    ``<dataset>_cnn_prob.pt``, in ``context.cnn_precision``); ``corner`` is not needed (a
    :class:`~nbv_prob_cnn.planners.base.CompletionHook`)."""
    from nbv_prob_cnn.completion import complete

    return complete(state, dataset=context.defaults.name, precision=context.cnn_precision)


def probability_map(
    method: GainMethod, state: np.ndarray, context: PlanningContext, origins: np.ndarray | None = None
) -> np.ndarray | None:
    """The probabilistic map ``P`` the method ray-casts on (None for ``ig``); CNN maps come from
    ``context.completion`` when set, else from the CNN in this process: with ``origins``, only over
    what their rays read (:func:`~nbv_prob_cnn.planners.local_completion.local_completion`). With
    ``origins`` and ``context.cnn_window`` the window around them is completed alone, by
    ``context.completion`` when set (a completion service), else here."""
    if method.probability is None:
        return None
    if method.probability == "constant":
        return probability_with_constant(state, context.defaults.p0)
    if method.probability == "oracle":
        if context.ground_truth is None:
            raise ValueError(f"{method.name}: needs the ground truth (context.ground_truth)")
        return probability_from_truth(state, context.ground_truth)
    if origins is not None and (context.completion is None or context.cnn_window is not None):
        from nbv_prob_cnn.planners.local_completion import local_completion

        return local_completion(state, context, origins)
    return (context.completion or cnn_completion)(state, context)


def method_origins(
    method: GainMethod,
    state: np.ndarray,
    context: PlanningContext,
    origin_filter: OriginFilter | None = None,
) -> np.ndarray:
    """Candidate origins of the method: the context's, narrowed by ``origin_filter`` (e.g. a
    reachable box), then for the downsampled method a random subset of fixed size."""
    origins = filtered_origins(state, context, origin_filter)
    count = DOWNSAMPLED_ORIGINS[state.ndim]
    if method.downsampled and origins.shape[0] > count:
        keep = np.sort(context.rng.choice(origins.shape[0], size=count, replace=False))
        origins = origins[keep]
    return origins


class GainPlanner(RankingPlanner):
    """Any gain-based method: probability map (timed as ``cnn``), then the view search, here or
    through ``context.ranker`` (which then receives the CNN map, if the method uses one)."""

    def __init__(self, method: GainMethod) -> None:
        self.method = method
        self.name = method.name

    def rank(
        self,
        state: np.ndarray,
        context: PlanningContext,
        top_k: int = 1,
        origin_filter: OriginFilter | None = None,
        view_mask: ViewMask | None = None,
    ) -> list[ViewChoice]:
        """The ``top_k`` best views, best first (empty if no view has positive gain).
        ``view_mask``: orientations allowed per origin (local search only; a remote ranker
        ignores it)."""
        uses_cnn = self.method.probability == "cnn"
        origins = window_origins = None
        if context.ranker is None:
            origins = self.candidates(state, context, origin_filter)
        elif uses_cnn and context.cnn_window is not None:  # the ranker searches them; the CNN window needs their box
            window_origins = self.candidates(state, context, origin_filter)
        start = time.perf_counter()
        prob = (
            probability_map(self.method, state, context, origins if origins is not None else window_origins)
            if (uses_cnn or origins is not None) else None
        )  # fmt: skip
        t_prob = time.perf_counter() - start
        if origins is None:
            assert context.ranker is not None
            found = context.ranker(self.name, state, prob, top_k)
        else:
            rerank = self.method.surface and context.image_rerank > 1
            found = search_views(
                state, prob, origins, context, self.method.mode, max(top_k, context.image_rerank) if rerank else top_k,
                view_mask=view_mask, probability=self.method.probability, surface=self.method.surface,
            )  # fmt: skip
            if rerank:  # the search's best image_rerank views by their image rays, the rest in the search's order
                settings = context.gain_settings(self.method.mode, self.method.probability, self.method.surface)
                head, tail = found[: context.image_rerank], found[context.image_rerank :]
                found = (rerank_by_image(state, prob, head, context, settings, reach=origins) + tail)[:top_k]
        surface_map = prob if prob is not None else probability_with_constant(state, context.defaults.p0)
        estimate = functools.partial(self._best_new_surface, state, surface_map, context, origin_filter, origins)
        for choice in found:
            choice.times["cnn"] = t_prob if uses_cnn else 0.0
            choice.surface_estimate = estimate
        return found

    def _best_new_surface(self, state, surface_map, context, origin_filter, origins) -> float:
        """:func:`~nbv_prob_cnn.planners.surface_stop.best_new_surface` over this ranking's candidates."""
        if origins is None:
            origins = self.candidates(state, context, origin_filter)
        return best_new_surface(state, surface_map, origins, context)

    def candidates(
        self, state: np.ndarray, context: PlanningContext, origin_filter: OriginFilter | None = None
    ) -> np.ndarray:
        """The origins searched: the method's (:func:`method_origins`) within the rays' reach of unknown
        space (the others cannot gain), ``int32`` (half the memory while the CNN runs)."""
        origins = method_origins(self.method, state, context, origin_filter)
        return near_unknown_origins(state, origins, ray_reach(context.active_sensor.r_max)).astype(np.int32)
