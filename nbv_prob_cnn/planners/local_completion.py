"""The completion CNN of a view search, over what the search reads (docs/performance.md#scale).

The rays from the candidate origins read only the box of the origins grown by the rays' reach
(:func:`~nbv_prob_cnn.planners.candidates.reach_region`): :func:`local_completion` runs the CNN
there only, by tiles (:func:`~nbv_prob_cnn.completion.tiled.complete_region`), which equals the
whole-grid map on every cell a ray reads (to float rounding). With ``context.cnn_window`` (a margin
in cells) the CNN completes only a window, the origins' box grown by that margin, and the unknown
cells outside it take the constant prior ``p0`` of Prob. IG
(:func:`~nbv_prob_cnn.completion.tiled.complete_window`): a cost that follows the workspace instead
of the room, at the price measured in docs/performance.md#scale.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.planners.base import PlanningContext
from nbv_prob_cnn.planners.candidates import grown_box, ray_reach, reach_region


def local_completion(state: np.ndarray, context: PlanningContext, origins: np.ndarray) -> np.ndarray:
    """The probabilistic map for a view search from ``origins`` (``(N, dims)`` cells): the context's
    data set's CNN (in ``context.cnn_precision``) over the cells the rays can read (``context.cnn_window``
    None), or over the window around the origins, ``p0`` on the other unknown cells: the window's map from
    ``context.completion`` when set (a completion service, sent the window's grid alone), else from the CNN
    here."""
    from nbv_prob_cnn.completion.tiled import complete_region, complete_window

    p0, dataset, precision = context.defaults.p0, context.defaults.name, context.cnn_precision
    if origins.shape[0] == 0:
        return probability_with_constant(state, p0)
    if context.cnn_window is None:
        region = reach_region(origins, ray_reach(context.active_sensor.r_max), state.shape)
        return complete_region(state, region, dataset=dataset, fill=p0, precision=precision)
    window = grown_box(origins, (context.cnn_window,) * state.ndim, state.shape)
    assert window is not None
    hook = context.completion
    if hook is None:
        return complete_window(state, window, p0, dataset=dataset, precision=precision)
    # a completion service: it gets the window's grid alone
    return complete_window(state, window, p0, completion=lambda inner, corner: hook(inner, context, corner=corner))
