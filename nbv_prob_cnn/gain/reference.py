"""Plain numpy reference of the ray gain (SPEC §4): the literal equations, no early stop.

It is the readable implementation the OpenCL kernel is tested against (vectorized over
origins and rays, a Python loop over the samples ``t``).
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.gain.directions import distance_weights, sample_offsets

_CHUNK = 2048  # origins per block, bounds the (chunk, R, dims) temporaries


def _sample(state: np.ndarray, values: np.ndarray, outside: float, origins: np.ndarray, offset_t: np.ndarray):
    """``values`` at sample cells ``origins[:, None] + offset_t[None]`` (``outside`` where a
    cell is outside the grid), plus the state there (1 = occupied outside)."""
    cells = origins[:, None, :] + offset_t[None, :, :].astype(np.int64)
    inside = np.all((cells >= 0) & (cells < np.array(state.shape)), axis=2)
    index = tuple(np.clip(cells, 0, np.array(state.shape) - 1).transpose(2, 0, 1))
    return np.where(inside, values[index], outside), np.where(inside, state[index], 1)


def ray_terms(
    state: np.ndarray, prob: np.ndarray, directions: np.ndarray, r_max: int, origins: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``H(v, h)`` and ``M(v, h)`` of equations (4)–(5), each ``(N, R)`` float64.

    ``p`` is read from ``prob`` in unknown cells only; known cells use 0 (empty) and 1
    (occupied). Cells outside the grid count as known occupied (``p = 1``, ``o = 1``).
    """
    weights = distance_weights(r_max, state.ndim)
    offsets = sample_offsets(directions, r_max)
    hit = np.zeros((origins.shape[0], directions.shape[0]))
    miss = np.zeros_like(hit)
    for start in range(0, origins.shape[0], _CHUNK):
        block = slice(start, start + _CHUNK)
        visible = np.ones_like(hit[block])  # Pr(r_t) = prod_{i<t} (1 - p(v_i))
        for t in range(r_max + 1):
            p_unknown, value = _sample(state, prob, 1.0, origins[block], offsets[:, t])
            unknown = value == -1
            p = np.where(unknown, p_unknown, value == 1)
            hit[block] += unknown * visible * weights[t]
            miss[block] += np.where(unknown, 1.0 - visible, 1.0) * weights[t]
            visible = visible * (1.0 - p)
    return hit, miss


def ray_gains_reference(
    state: np.ndarray, prob: np.ndarray, directions: np.ndarray, r_max: int, origins: np.ndarray
) -> np.ndarray:
    """``G_r = H / (H + M)`` (equation (6)), ``(N, R)`` float32."""
    hit, miss = ray_terms(state, prob, directions, r_max, origins)
    return (hit / (hit + miss)).astype(np.float32)


def ig_gains_reference(
    state: np.ndarray, directions: np.ndarray, r_max: int, origins: np.ndarray, min_range: float = 0.0
) -> np.ndarray:
    """Non-probabilistic information gain: each ray stops at its first non-empty sample and
    scores ``t^nu / sum_t t^nu`` if that sample is unknown with ``min_range <= t <= r_max``."""
    weights = distance_weights(r_max, state.ndim)
    offsets = sample_offsets(directions, r_max)
    gains = np.zeros((origins.shape[0], directions.shape[0]))
    for start in range(0, origins.shape[0], _CHUNK):
        block = slice(start, start + _CHUNK)
        running = np.ones(gains[block].shape, dtype=bool)
        for t in range(r_max + 1):
            _, value = _sample(state, state, 1, origins[block], offsets[:, t])
            stops = running & (value != 0)
            gains[block] += np.where(stops & (value == -1) & (t >= min_range), weights[t], 0.0)
            running &= ~stops
    return (gains / weights.sum()).astype(np.float32)
