"""The City-CNN baselines as planners (``flat_city_cnn``, ``b_city_cnn``, ``d_city_cnn``): the
network predicts view (or ray) gains from ``E`` and ``F``; the best predicted view wins.

They read their trained weights ``nbv_prob_cnn/weights/<dataset>_<method>.pt`` (missing weights:
an error naming the ``nbv train`` command). The sensor they were trained for is the data set's;
the context's sensor and ``n_rays`` overrides do not apply to them.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from nbv_prob_cnn.city_cnn import CityGeometry, decode_views, encode_city_input, output_mask
from nbv_prob_cnn.grid import check_state
from nbv_prob_cnn.planners.base import OriginFilter, PlanningContext, RankingPlanner, ViewChoice


def predict(method: str, state: np.ndarray, context: PlanningContext) -> np.ndarray:
    """The masked network output ``(C, *out_spatial)`` of a City-CNN on ``state``."""
    from nbv_prob_cnn.completion.inference import load_model, resolve_device

    device = resolve_device(None)
    model = load_model(None, context.defaults.name, device, model_name=method)
    if model.dims != state.ndim:
        raise ValueError(f"state: a {state.ndim}D grid does not fit a {model.dims}D {method} network")
    with torch.inference_mode():
        output = model(encode_city_input(state[None]).to(device))[0].float().cpu().numpy()
    return output * output_mask(CityGeometry.of(method, context.defaults), state)


class CityCnnPlanner(RankingPlanner):
    """One of the three City-CNN variants (by name)."""

    def __init__(self, method: str) -> None:
        self.name = method

    def rank_here(
        self, state: np.ndarray, context: PlanningContext, top_k: int, origin_filter: OriginFilter | None
    ) -> list[ViewChoice]:
        state = check_state(state)
        start = time.perf_counter()
        output = predict(self.name, state, context)
        t_cnn = time.perf_counter() - start
        origins = CityGeometry.of(self.name, context.defaults).origins(state)
        if origin_filter is not None:
            origins = origin_filter(origins)
        if origins.shape[0] == 0:
            return []
        views = decode_views(self.name, output, state, context.defaults, origins).ravel()
        k = min(max(1, top_k), views.size)
        best = np.argpartition(-views, k - 1)[:k] if k < views.size else np.arange(views.size)
        best = best[np.lexsort((best, -views[best]))]
        n_views = views.size // origins.shape[0]
        times = {"cnn": t_cnn, "raycast": 0.0, "views": time.perf_counter() - start - t_cnn}
        return [
            ViewChoice(origins[i // n_views].copy(), int(i % n_views), float(views[i]), dict(times))
            for i in best
            if views[i] > 0.0
        ]
