"""Ternary occupancy grids (docs/method.md#grids): values, derived channels and input validation.

A grid is an ``int8`` array indexed ``[x, y]`` or ``[x, y, z]`` with
``UNKNOWN = -1``, ``EMPTY = 0``, ``OCCUPIED = 1``. A probabilistic map is a ``float32``
array of the same shape with values in [0, 1]. Ground truth is a binary grid.
"""

from __future__ import annotations

import numpy as np

UNKNOWN = -1
EMPTY = 0
OCCUPIED = 1


def lattice_index(ndim: int, stride: int) -> tuple[slice, ...]:
    """The index of every ``stride``-th cell along each of ``ndim`` axes (``a[lattice_index(a.ndim, s)]``:
    the cells whose every coordinate is a multiple of ``s``)."""
    return (slice(None, None, stride),) * ndim


def check_state(state: np.ndarray, name: str = "state") -> np.ndarray:
    """Validate a ternary grid and return it as a C-contiguous ``int8`` array.

    Raises:
        ValueError: not a numpy array, not 2D/3D, an empty dimension, a non-integer dtype
            or values outside {-1, 0, 1}.
    """
    if not isinstance(state, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(state).__name__}")
    if state.ndim not in (2, 3):
        raise ValueError(f"{name}: expected a 2D or 3D grid, got shape {state.shape}")
    if min(state.shape) == 0:
        raise ValueError(f"{name}: grid has an empty dimension, shape {state.shape}")
    if not np.issubdtype(state.dtype, np.integer):
        raise ValueError(f"{name}: expected an integer (int8) grid of -1/0/1, got dtype {state.dtype}")
    lo, hi = int(state.min()), int(state.max())
    if lo < UNKNOWN or hi > OCCUPIED:
        raise ValueError(f"{name}: values must be -1 (unknown), 0 (empty) or 1 (occupied); found range [{lo}, {hi}]")
    return np.ascontiguousarray(state, dtype=np.int8)


def check_probability(prob: np.ndarray, shape: tuple[int, ...], name: str = "prob") -> np.ndarray:
    """Validate a probabilistic map of the given shape; return it as C-contiguous ``float32``.

    Raises:
        ValueError: wrong type/shape, non-float dtype, NaN/inf or values outside [0, 1].
    """
    if not isinstance(prob, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(prob).__name__}")
    if prob.shape != tuple(shape):
        raise ValueError(f"{name}: shape {prob.shape} does not match the grid shape {tuple(shape)}")
    if not np.issubdtype(prob.dtype, np.floating):
        raise ValueError(f"{name}: expected a float32 probability map, got dtype {prob.dtype}")
    if not np.all(np.isfinite(prob)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    if prob.size and (prob.min() < 0.0 or prob.max() > 1.0):
        raise ValueError(f"{name}: probabilities must lie in [0, 1]; found [{prob.min()}, {prob.max()}]")
    return np.ascontiguousarray(prob, dtype=np.float32)


def check_ground_truth(
    truth: np.ndarray, shape: tuple[int, ...] | None = None, name: str = "ground_truth"
) -> np.ndarray:
    """Validate a binary ground-truth grid (1 occupied, 0 empty); return it as ``uint8``."""
    if not isinstance(truth, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(truth).__name__}")
    if truth.ndim not in (2, 3):
        raise ValueError(f"{name}: expected a 2D or 3D grid, got shape {truth.shape}")
    if shape is not None and truth.shape != tuple(shape):
        raise ValueError(f"{name}: shape {truth.shape} does not match the grid shape {tuple(shape)}")
    if truth.dtype != np.bool_:
        if not np.issubdtype(truth.dtype, np.integer):
            raise ValueError(f"{name}: expected a binary (bool/uint8) grid, got dtype {truth.dtype}")
        if truth.size and (truth.min() < 0 or truth.max() > 1):
            raise ValueError(f"{name}: values must be 0 (empty) or 1 (occupied)")
    return np.ascontiguousarray(truth, dtype=np.uint8)


def frontier_mask(state: np.ndarray) -> np.ndarray:
    """``F``: unknown cells with at least one empty face neighbour (4-/6-connectivity)."""
    empty = state == EMPTY
    near_empty = np.zeros_like(empty)
    for axis in range(state.ndim):
        lead = [slice(None)] * state.ndim
        trail = [slice(None)] * state.ndim
        lead[axis], trail[axis] = slice(1, None), slice(None, -1)
        near_empty[tuple(lead)] |= empty[tuple(trail)]
        near_empty[tuple(trail)] |= empty[tuple(lead)]
    return near_empty & (state == UNKNOWN)


def unknown_fraction(state: np.ndarray, ground_truth: np.ndarray) -> float:
    """Ground-truth-empty cells not yet observed / ground-truth-empty cells
    (docs/method.md#exploration-protocol-and-metrics)."""
    free = ground_truth == 0
    n_free = int(free.sum())
    if n_free == 0:
        return 0.0
    return float(np.count_nonzero(free & (state == UNKNOWN)) / n_free)


def unknown_fraction_all(state: np.ndarray) -> float:
    """Unknown cells / all cells."""
    return float(np.count_nonzero(state == UNKNOWN) / state.size)


def probability_with_constant(state: np.ndarray, p0: float) -> np.ndarray:
    """Probabilistic map with ``p0`` in unknown cells (Prob. IG), 0 empty, 1 occupied (``float32``;
    masked writes into one new array: a tenth of the time of chained ``np.where`` on 29.7 M cells).

    Raises:
        ValueError: ``p0`` is not a probability (a finite number in [0, 1]).
    """
    if not 0.0 <= float(p0) <= 1.0:  # NaN fails too
        raise ValueError(f"p0: expected a probability in [0, 1], got {p0}")
    prob = np.full(np.shape(state), np.float32(p0), dtype=np.float32)
    prob[state == EMPTY] = 0.0
    prob[state == OCCUPIED] = 1.0
    return prob


def probability_from_truth(state: np.ndarray, ground_truth: np.ndarray) -> np.ndarray:
    """Probabilistic map with the ground truth in unknown cells (Omniscient)."""
    prob = np.where(state == UNKNOWN, ground_truth.astype(np.float32), (state == OCCUPIED).astype(np.float32))
    return prob.astype(np.float32, copy=False)
