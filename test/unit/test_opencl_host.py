"""The host-side grids and indices of the OpenCL search (nbv_prob_cnn.gain.marched_grid, search_bounds), against slow
references written here: an exact distance transform, per-cell window loops, np.unique and a full
stable sort."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.ndimage import distance_transform_cdt

from nbv_prob_cnn.gain.marched_grid import (
    CODE_EMPTY,
    CODE_OCCUPIED,
    ORIGINAL_BORDER_CODE,
    empty_distance,
    encode_grid,
    linear_indices,
    march_grid,
)
from nbv_prob_cnn.gain.search_bounds import BoundOrder, bound_grid, origin_blocks


def _state(shape: tuple[int, ...], seed: int, unknown: float = 0.3, occupied: float = 0.1) -> np.ndarray:
    draw = np.random.default_rng(seed).random(shape)
    return np.where(draw < unknown, -1, np.where(draw < unknown + occupied, 1, 0)).astype(np.int8)


def test_encode_grid_by_hand() -> None:
    state = np.array([[-1, 0], [1, -1]], dtype=np.int8)
    prob = np.array([[0.25, 0.5], [0.75, 1.0]])
    assert encode_grid(state, prob).tolist() == [[0.25, CODE_EMPTY], [CODE_OCCUPIED, 1.0]]
    assert encode_grid(state, None).tolist() == [[0.0, CODE_EMPTY], [CODE_OCCUPIED, 0.0]]
    assert encode_grid(state, prob).dtype == np.float32


@pytest.mark.parametrize("shape", [(9, 8, 7), (16, 5, 11), (13, 12)])
@pytest.mark.parametrize("free", [0.6, 0.97])
def test_empty_distance_is_a_lower_bound_within_two_cells(shape: tuple[int, ...], free: float) -> None:
    empty = np.random.default_rng(len(shape) + int(free * 100)).random(shape) < free
    padded = np.pad(empty, 1, constant_values=False)  # cells beyond the grid count as non-empty
    exact = distance_transform_cdt(padded, metric="chessboard")[tuple(slice(1, -1) for _ in shape)]
    bound = empty_distance(empty)
    assert bound.dtype == np.int32
    assert np.all(bound[~empty] == 0)
    assert np.all(bound[empty] >= 1)
    assert np.all(bound <= exact)
    assert np.all(bound >= exact - 2)


def test_empty_distance_by_hand() -> None:
    # one occupied cell at x = 0 of a 1 x 8 line (the y axis of size 1 is the grid's edge: non-empty beyond)
    empty = np.ones((8, 1), dtype=bool)
    empty[0, 0] = False
    # every cell is next to the edge in y: the exact distance is 1 everywhere
    assert empty_distance(empty)[:, 0].tolist() == [0, 1, 1, 1, 1, 1, 1, 1]
    wide = np.ones((12, 12), dtype=bool)
    wide[0, :] = False
    # exact distance of (x, 6): min(x, 12 - x, 6 + 1, 12 - 6); coarse cells of 2: lower by up to 2
    row = empty_distance(wide)[:, 6].tolist()
    exact = [0] + [min(x, 12 - x, 6) for x in range(1, 12)]
    assert all(e - 2 <= b <= e for b, e in zip(row, exact, strict=True)), (row, exact)
    # an open cube of 20 cells: 10 cells from the outside at its centre, long jumps
    assert 8 <= empty_distance(np.ones((20, 20, 20), dtype=bool))[10, 10, 10] <= 10


@pytest.mark.parametrize("border", [-1.0, ORIGINAL_BORDER_CODE])
def test_march_grid_codes(border: float) -> None:
    state = _state((7, 6, 5), 3)
    prob = np.random.default_rng(4).random(state.shape).astype(np.float32)
    march = march_grid(encode_grid(state, prob), border)
    assert march.shape == (9, 8, 7) and march.dtype == np.float32
    inner = march[1:-1, 1:-1, 1:-1]
    assert np.array_equal(inner[state == -1], prob[state == -1])
    assert np.all(inner[state == 1] == -1.0)
    empty_codes = inner[state == 0]
    assert np.all(empty_codes <= -2.0) and np.all(empty_codes == np.round(empty_codes))
    faces = np.ones(march.shape, dtype=bool)
    faces[1:-1, 1:-1, 1:-1] = False
    assert np.all(march[faces] == np.float32(border))


def test_march_grid_2d_pads_x_and_y_only() -> None:
    state = _state((6, 5), 5)
    march = march_grid(encode_grid(state, None))
    assert march.shape == (8, 7, 1)
    assert np.all(march[0] == -1.0) and np.all(march[:, -1] == -1.0)
    assert np.all(march[1:-1, 1:-1, 0][state == 0] <= -2.0)


def test_linear_indices_against_ravel_multi_index() -> None:
    cells = np.random.default_rng(1).integers(0, 5, (50, 3))
    shape = (7, 8, 9)
    assert np.array_equal(linear_indices(cells, shape, shift=1), np.ravel_multi_index((cells + 1).T, shape))
    offsets = np.random.default_rng(2).integers(-2, 3, (20, 2))
    assert np.array_equal(linear_indices(offsets, (7, 8, 1), shift=0), offsets[:, 0] * 8 + offsets[:, 1])
    assert linear_indices(cells, shape, shift=1).dtype == np.int32


@pytest.mark.parametrize("size", [2, 3, 4])
@pytest.mark.parametrize("dims", [2, 3])
def test_origin_blocks_against_unique_corners(size: int, dims: int) -> None:
    origins = np.random.default_rng(size * dims).integers(0, 11, (300, dims))
    corners, block_of = origin_blocks(origins, size)
    padded = np.zeros((len(origins), 3), dtype=np.int64)
    padded[:, :dims] = origins + 1
    # the corner of padded cell c: the smallest multiple of size >= c (blocks 1..size, size+1..2 size, ...)
    corner_of = padded.copy()
    corner_of[:, :dims] = -(-padded[:, :dims] // size) * size
    expected, inverse = np.unique(corner_of, axis=0, return_inverse=True)
    assert np.array_equal(corners, expected)
    assert np.array_equal(block_of, inverse.ravel())
    assert np.all((padded[:, :dims] <= corners[block_of, :dims]) & (padded[:, :dims] > corners[block_of, :dims] - size))
    no_corners, no_blocks = origin_blocks(origins[:0], size)
    assert no_corners.shape == (0, 3) and no_blocks.shape == (0,)


def _bound_reference(padded: np.ndarray, dims: int, probabilistic: bool, size: int) -> np.ndarray:
    """bound_grid's documented value, cell by cell."""
    pad = ((size, size), (size, size), (size, size) if dims == 3 else (0, 0))
    grid = np.pad(padded, pad, constant_values=np.float32(-1.0))
    out = np.empty_like(grid)
    windows = list(itertools.product(range(size), repeat=dims))
    for c in np.ndindex(grid.shape):
        values = []
        for w in windows:
            cell = list(c)
            for axis in range(dims):
                cell[axis] -= w[axis]
            values.append(grid[tuple(cell)] if min(cell) >= 0 else np.float32(-1.0))  # outside: occupied
        values = np.array(values, dtype=np.float32)
        if np.all(values == -1.0):
            out[c] = -1.0
        elif np.any(values >= 0.0):
            p = np.where(values >= 0.0, values if probabilistic else 0.0, np.where(values == -1.0, 1.0, 0.0))
            out[c] = p.min()
        else:
            out[c] = values[values <= -2.0].max()
    return out


@pytest.mark.parametrize("size", [2, 3, 4])
@pytest.mark.parametrize("probabilistic", [True, False])
@pytest.mark.parametrize("dims", [2, 3])
def test_bound_grid_against_cell_by_cell_reference(size: int, probabilistic: bool, dims: int) -> None:
    shape = (6, 5, 4) if dims == 3 else (7, 6)
    state = _state(shape, size + 10 * dims, unknown=0.15, occupied=0.2)
    prob = np.random.default_rng(size).random(shape).astype(np.float32)
    padded = march_grid(encode_grid(state, prob))
    got = bound_grid(padded, dims, probabilistic, size)
    assert np.array_equal(got, _bound_reference(padded, dims, probabilistic, size))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bound_order_is_the_stable_sort_of_every_origin(seed: int) -> None:
    rng = np.random.default_rng(seed)
    blocks = 40
    block_bound = rng.integers(0, 6, blocks).astype(np.float32)  # many ties
    block_of = rng.integers(0, blocks, 1000)
    rank = np.empty(blocks, dtype=np.int64)
    rank[np.argsort(-block_bound, kind="stable")] = np.arange(blocks)
    order = np.argsort(rank[block_of], kind="stable")
    ordered = BoundOrder(block_bound, block_of)
    start = 0
    for stop in (1, 3, 64, 65, 300, 1000):  # growing takes, as the search's batches
        origins, bounds = ordered.take(start, stop)
        assert np.array_equal(origins, order[start:stop])
        assert np.array_equal(bounds, block_bound[block_of[order[start:stop]]])
        start = stop
    assert np.array_equal(ordered.take(0, 1000)[0], order)
