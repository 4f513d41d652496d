"""Hand-worked gain grids shared by the gain tests (test_gain, test_gain_surface)."""

from __future__ import annotations

import numpy as np

E, O, U = 0, 1, -1  # noqa: E741


def row_world(values, probs, height=3) -> tuple[np.ndarray, np.ndarray]:
    """A 2D grid whose middle row y=1 holds ``values``/``probs`` (other rows occupied)."""
    state = np.full((len(values), height), O, dtype=np.int8)
    prob = np.ones(state.shape, dtype=np.float32)
    state[:, 1] = values
    prob[:, 1] = probs
    prob[state == E] = 0.0
    return state, prob
