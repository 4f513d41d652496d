"""Candidate origins that can gain, and the part of the grid their rays read (docs/performance.md#scale).

A view's gain counts unknown cells only (``H`` of docs/method.md#probabilistic-ray-casting-gain), and a
ray from origin ``v`` samples ``v + round(t b)`` for ``t <= R_max``: cells within Chebyshev distance
``R_max`` of ``v`` (the paper's rounded samples; exact voxel traversal one cell further, hence
:func:`ray_reach` adds a cell). So

* an empty cell with no unknown cell within that distance has gain 0 in every view: the *frontier
  band* (:func:`frontier_band`), the empty cells within sensor range of unknown space, holds every
  origin of positive gain, and a search over it returns what the dense search over every empty cell
  returns (views of zero gain are never returned);
* the rays from a set of origins read only the cells of their bounding box grown by the reach
  (:func:`reach_region`): the probabilistic map is needed there only.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.basics.grid import EMPTY, UNKNOWN, lattice_index
from nbv_prob_cnn.basics.region import Region, region_slices


def ray_reach(r_max: int) -> int:
    """Chebyshev distance (cells) a ray of range ``r_max`` can sample from its origin, with a cell
    of margin for the exact traversal's sampling."""
    if not isinstance(r_max, (int, np.integer)) or r_max < 1:
        raise ValueError(f"r_max: expected a positive range in cells, got {r_max!r}")
    return int(r_max) + 1


def _any_within(mask: np.ndarray, reach: int, axis: int) -> np.ndarray:
    """Along ``axis``: some cell of ``mask`` lies within ``reach`` cells (a running count from a
    cumulative sum: count up to ``i + reach`` minus count up to ``i - reach - 1``)."""
    n = mask.shape[axis]
    if reach >= n - 1:  # the window covers the whole axis
        return np.broadcast_to(mask.any(axis=axis, keepdims=True), mask.shape)
    count = np.cumsum(mask, axis=axis, dtype=np.int16 if n < 2**15 else np.int32)
    moved = np.moveaxis(count, axis, 0)
    upper = np.empty_like(moved)
    upper[: n - reach] = moved[reach:]
    upper[n - reach :] = moved[n - 1]
    upper[reach + 1 :] -= moved[: n - reach - 1]
    return np.moveaxis(upper > 0, 0, axis)


def dilate(mask: np.ndarray, reach: int) -> np.ndarray:
    """Bool grid: a cell of ``mask`` lies within Chebyshev distance ``reach`` (separable: one running
    count per axis)."""
    if reach < 0:
        raise ValueError(f"reach: expected a distance in cells >= 0, got {reach!r}")
    near = mask
    for axis in range(mask.ndim):
        near = _any_within(near, reach, axis)
    return np.asarray(near)


def near_unknown(state: np.ndarray, reach: int) -> np.ndarray:
    """Bool grid: an unknown cell lies within Chebyshev distance ``reach``."""
    return dilate(state == UNKNOWN, reach)


def near_unknown_origins(state: np.ndarray, origins: np.ndarray, reach: int, block: int = 4) -> np.ndarray:
    """The ``origins`` (``(N, dims)`` cells, order kept) whose block of ``block`` cells per axis lies
    within ``ceil(reach / block)`` blocks of a block holding an unknown cell: every origin within
    Chebyshev distance ``reach`` of an unknown cell (the ones that can have a positive gain) and a few
    up to ``block`` cells further, at ``1 / block**dims`` of the cost of the cell-exact test."""
    if origins.shape[0] == 0:
        return origins
    unknown = state == UNKNOWN
    shape = [-(-n // block) for n in state.shape]
    padded = np.zeros([n * block for n in shape], dtype=bool)
    padded[tuple(slice(0, n) for n in state.shape)] = unknown
    split = [v for n in shape for v in (n, block)]
    coarse = np.asarray(padded.reshape(split).any(axis=tuple(range(1, 2 * state.ndim, 2))))
    near = dilate(coarse, -(-reach // block))
    if near.all():  # e.g. a grid within the rays' reach everywhere: every origin stays
        return origins
    return origins[near[tuple((np.asarray(origins) // block).T)]]


def frontier_band(state: np.ndarray, reach: int, stride: int = 1) -> np.ndarray:
    """Empty cells within Chebyshev distance ``reach`` of an unknown cell, on the ``stride`` lattice
    (every coordinate a multiple of ``stride``), ``(N, dims)`` in ``np.argwhere`` order: the empty
    origins of :func:`~nbv_prob_cnn.gain.empty_origins` that can have a positive gain."""
    if not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ValueError(f"stride: expected a positive integer, got {stride!r}")
    keep = lattice_index(state.ndim, stride)
    lattice = state[keep]
    band = (lattice == EMPTY) & near_unknown(state, reach)[keep]
    cells = np.argwhere(band)
    return cells * stride if stride > 1 else cells


def reach_region(origins: np.ndarray, reach: int, shape: tuple[int, ...]) -> Region | None:
    """The cells the rays from ``origins`` can read: their bounding box grown by ``reach``, clipped
    to the grid; None when there are no origins."""
    return grown_box(origins, (reach,) * len(shape), shape)


def grown_box(origins: np.ndarray, margin: tuple[int, ...], shape: tuple[int, ...]) -> Region | None:
    """The bounding box of ``origins`` grown by ``margin`` cells per axis, clipped to the grid (None:
    no origins)."""
    if origins.shape[0] == 0:
        return None
    lo = np.maximum(origins.min(axis=0) - np.asarray(margin), 0)
    hi = np.minimum(origins.max(axis=0) + np.asarray(margin) + 1, shape)
    return tuple(int(v) for v in lo), tuple(int(v) for v in hi)


def crop_to_reach(
    state: np.ndarray, prob: np.ndarray | None, origins: np.ndarray, r_max: int
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """The grid, map and origins cut to the box the rays from ``origins`` can read
    (:func:`reach_region`), and the box's corner ``shift`` (cells in the whole grid = cells in the box
    + ``shift``). A search on the box reads the same cells as on the whole grid. The inputs
    unchanged (``shift`` 0) when the box is the whole grid or the origins are not ``(N, dims)``."""
    shift = np.zeros(state.ndim, dtype=np.int64)
    origins = np.asarray(origins)
    if origins.ndim != 2 or origins.shape[1] != state.ndim or not np.issubdtype(origins.dtype, np.integer):
        return state, prob, origins, shift
    region = reach_region(origins, ray_reach(r_max), state.shape)
    if region is None or region == ((0,) * state.ndim, tuple(state.shape)):
        return state, prob, origins, shift
    crop = region_slices(region)
    shift[:] = region[0]
    cropped_prob = None if prob is None else np.ascontiguousarray(prob[crop])
    return np.ascontiguousarray(state[crop]), cropped_prob, origins - shift, shift
