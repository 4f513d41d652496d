"""Upper bounds of the coarse-to-fine best-view search (:meth:`~nbv_prob_cnn.gain.opencl.OpenCLRayCaster.best_view`):
origins grouped in blocks, the grid whose marched gain from a block's corner bounds every origin of
the block, and the origins in order of decreasing block bound."""

from __future__ import annotations

import numpy as np


def origin_blocks(origins: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The blocks of ``size`` cells per marched axis that hold ``origins`` (``(N, dims)`` cells of the
    unpadded grid): their corners ``c`` in padded coordinates (``(B, 3)`` int64, in C order; the
    block is ``c - {0 .. size-1}`` per marched axis: padded coordinates ``1 .. size``,
    ``size + 1 .. 2 size``, ...), and per origin its block ``(N,)`` (an index into the corners).
    One flag per block of a dense block grid instead of a sort of the origins."""
    dims = origins.shape[1]
    if origins.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    block = [(origins[:, axis].astype(np.int64) + size) // size for axis in range(dims)]
    counts = tuple(int(b.max()) + 1 for b in block)
    key = np.ravel_multi_index(block, counts)
    present = np.zeros(int(np.prod(counts)), dtype=bool)
    present[key] = True
    index = np.cumsum(present, dtype=np.int64) - 1
    corners = np.zeros((int(index[-1]) + 1, 3), dtype=np.int64)
    corners[:, :dims] = np.stack(np.unravel_index(np.flatnonzero(present), counts), axis=1) * size
    return corners, index[key]


def _window(values: np.ndarray, dims: int, size: int, reduce: np.ufunc, fill) -> np.ndarray:
    """``reduce`` over the window ``c - {0 .. size-1}`` per marched axis (``fill`` outside), by
    doubling windows: ``ceil(log2 size)`` whole-grid operations per axis."""
    out = values
    for axis in range(dims):
        width = 1
        while width < size:
            step = min(width, size - width)
            moved = np.moveaxis(out, axis, 0)
            wider = np.empty_like(moved)
            reduce(moved[step:], moved[:-step], out=wider[step:])
            reduce(moved[:step], fill, out=wider[:step])
            out, width = np.moveaxis(wider, 0, axis), width + step
    return out


def _grown(padded: np.ndarray, dims: int, size: int) -> np.ndarray:
    """``padded`` grown by ``size`` occupied cells (-1) on each side of every marched axis."""
    pad = ((size, size), (size, size), (size, size) if dims == 3 else (0, 0))
    return np.pad(padded, pad, constant_values=np.float32(-1.0))


def bound_grid(padded: np.ndarray, dims: int, probabilistic: bool, size: int) -> np.ndarray:
    """The grid whose marched gain from a block corner ``c`` bounds, ray by ray, the gain of
    every cell of the block ``c - {0 .. size-1}^dims`` (see :meth:`OpenCLRayCaster.best_view`).

    ``padded`` grown by ``size`` occupied cells on each side of every marched axis (the corner's
    ray stops only once all the block's rays have stopped, up to ``size - 1`` cells after the
    padding); cell ``c`` summarises the window ``c - {0 .. size-1}^dims`` (cells outside count as
    occupied): ``-1`` if the whole window is occupied (every ray of the block has stopped);
    else, if the window holds an unknown cell, the smallest occupancy probability in it (empty
    0, occupied 1; 0 when not ``probabilistic``): the block's samples there count at most the
    full weight and let through at most ``1 - min p``; else (empty and occupied cells only) the
    empty code of the smallest distance in the window (samples closer than it are empty for the
    whole block).

    Two window reductions: the largest of a key (occupied -inf, empty its code <= -2, unknown +1)
    tells the three cases apart and gives the empty code; the smallest ``p`` the second case.
    """
    grid = _grown(padded, dims, size)
    unknown, occupied = grid >= 0.0, grid == -1.0
    key = grid.copy()  # empty codes stay
    np.copyto(key, np.float32(1.0), where=unknown)
    np.copyto(key, np.float32(-np.inf), where=occupied)
    out = _window(key, dims, size, np.maximum, np.float32(-np.inf))
    del key
    if probabilistic:
        p = grid  # our own copy: becomes p (unknown cells keep theirs)
        np.copyto(p, np.float32(0.0), where=grid <= -2.0)
        np.copyto(p, np.float32(1.0), where=occupied)
        np.copyto(out, _window(p, dims, size, np.minimum, np.float32(1.0)), where=out > 0.0)
    else:  # an unknown cell counts p = 0: the window's least p is 0 wherever it holds one
        np.copyto(out, np.float32(0.0), where=out > 0.0)
    out[out == -np.inf] = np.float32(-1.0)
    return np.ascontiguousarray(out, dtype=np.float32)


class BoundOrder:
    """The origins in order of decreasing block bound: blocks by bound (ties: the first block first),
    each block's origins in grid order, as a stable sort of every origin by its block's rank gives
    them. Sorted only as far as :meth:`take` reads (a search reads a small prefix; sorting millions
    of origins cost more than their exact gains)."""

    def __init__(self, block_bound: np.ndarray, block_of: np.ndarray) -> None:
        by_bound = np.argsort(-block_bound, kind="stable")
        rank = np.empty(block_bound.size, dtype=np.int64)
        rank[by_bound] = np.arange(block_bound.size)
        self._origin_rank = rank[block_of]
        self._rank_bound = block_bound[by_bound]
        self._ends = np.cumsum(np.bincount(self._origin_rank, minlength=block_bound.size))  # origins up to each rank
        self._order = np.zeros(0, dtype=np.int64)

    def take(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """Origins at positions ``start .. stop - 1`` of the order and their blocks' bounds."""
        if stop > self._order.size:  # the blocks holding the first max(stop, 2x) positions, at least
            ranks = int(np.searchsorted(self._ends, max(stop, 2 * self._order.size))) + 1
            members = np.flatnonzero(self._origin_rank < ranks)
            self._order = members[np.argsort(self._origin_rank[members], kind="stable")]
        following = self._order[start:stop]
        return following, self._rank_bound[self._origin_rank[following]]


def surface_bound_grid(padded: np.ndarray, dims: int, size: int) -> np.ndarray:
    """Beside :func:`bound_grid` for a surface blend (docs/method.md#surface-gain): per cell of the
    same grown grid, the largest occupancy probability of an unknown cell in the window
    ``c - {0 .. size-1}^dims`` (0 where the window holds none). A block's unknown sample at ``t``
    counts at most ``(1 - beta) + beta`` times that, while its visibility is bounded by the
    window's smallest ``p`` (:func:`bound_grid`)."""
    grid = _grown(padded, dims, size)
    p = np.where(grid >= 0.0, grid, np.float32(0.0)).astype(np.float32)
    return np.ascontiguousarray(_window(p, dims, size, np.maximum, np.float32(0.0)), dtype=np.float32)
