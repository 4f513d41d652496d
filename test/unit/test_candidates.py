"""Candidate origins that can gain (nbv_prob_cnn/planners/candidates.py): the frontier band against
independent distance computations, and the best views over it against the dense search."""

import numpy as np
import pytest
from scipy import ndimage

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.gain import empty_origins
from nbv_prob_cnn.planners import PlanningContext
from nbv_prob_cnn.planners.base import search_views
from nbv_prob_cnn.planners.candidates import frontier_band, grown_box, near_unknown, ray_reach, reach_region


def _state(rng, shape, p_unknown):
    return rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=shape, p=[p_unknown, 0.95 - p_unknown, 0.05])


@pytest.mark.parametrize("reach", [0, 1, 2, 5, 13, 40])
def test_near_unknown_is_a_chebyshev_dilation(rng, reach):
    state = _state(rng, (31, 22, 17), 0.003)
    expected = ndimage.maximum_filter((state == -1).astype(np.uint8), size=2 * reach + 1, mode="constant") > 0
    np.testing.assert_array_equal(near_unknown(state, reach), expected)
    flat = _state(rng, (40, 33), 0.01)
    expected = ndimage.maximum_filter((flat == -1).astype(np.uint8), size=2 * reach + 1, mode="constant") > 0
    np.testing.assert_array_equal(near_unknown(flat, reach), expected)


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_frontier_band_is_the_empty_cells_within_reach_of_unknown(rng, stride):
    state = _state(rng, (30, 26, 20), 0.002)
    reach = 4
    distance = ndimage.distance_transform_cdt(state != -1, metric="chessboard")  # to the nearest unknown
    every = empty_origins(state, stride)
    expected = every[distance[tuple(every.T)] <= reach]
    band = frontier_band(state, reach, stride)
    np.testing.assert_array_equal(band, expected)  # the same cells, in the same (argwhere) order
    assert 0 < band.shape[0] < every.shape[0]


def test_regions_are_bounding_boxes_grown_and_clipped():
    origins = np.array([[3, 4, 5], [10, 2, 7]])
    assert reach_region(origins, 2, (12, 12, 12)) == ((1, 0, 3), (12, 7, 10))
    assert grown_box(origins, (1, 0, 3), (20, 20, 20)) == ((2, 2, 2), (12, 5, 11))
    assert reach_region(np.zeros((0, 3), dtype=np.int64), 2, (4, 4, 4)) is None
    assert ray_reach(8) == 9
    with pytest.raises(ValueError, match="r_max"):
        ray_reach(0)
    with pytest.raises(ValueError, match="stride"):
        frontier_band(np.zeros((4, 4), dtype=np.int8), 2, 0)


@pytest.mark.parametrize("mode", ["prob", "ig"])
def test_the_band_keeps_the_dense_searchs_views(rng, mode):
    """A grid larger than the sensor range with little unknown space: the band drops most empty cells,
    and the best view and the top 20 are the dense search's (same cells, views and gains)."""
    defaults = DatasetDefaults("3du", 3, (40, 36, 30), 0.01, Sensor(60.0, 46.0, 8), 4, 3)
    context = PlanningContext(defaults, backend="opencl", origin_stride=1)
    state = _state(rng, defaults.shape, 0.0)
    state[28:34, 5:12, 20:26] = -1
    prob = probability_with_constant(state, 0.15)
    dense = empty_origins(state)
    band = frontier_band(state, ray_reach(context.active_sensor.r_max), 1)
    assert band.shape[0] < 0.5 * dense.shape[0]
    for top_k in (1, 20):
        want = search_views(state, prob, dense, context, mode, top_k)
        got = search_views(state, prob, band, context, mode, top_k)
        assert len(got) == len(want) == top_k
        for a, b in zip(got, want, strict=True):
            assert (tuple(a.cell), a.view_index, a.gain) == (tuple(b.cell), b.view_index, b.gain)


def test_a_search_from_a_corner_reads_only_its_reach(rng):
    """search_views cuts the grid to the origins' reach: the gains of a corner's origins, their best
    views and a view mask are those of the whole grid (origin_view_gains on it, no cut)."""
    from nbv_prob_cnn.gain import origin_view_gains

    defaults = DatasetDefaults("3du", 3, (44, 40, 30), 0.01, Sensor(60.0, 46.0, 8), 4, 3)
    context = PlanningContext(defaults, backend="opencl", origin_stride=1)
    state = _state(rng, defaults.shape, 0.3)
    prob = probability_with_constant(state, 0.15)
    every = empty_origins(state)
    corner = every[(every[:, 0] >= 30) & (every[:, 1] < 12)]
    gains = origin_view_gains(state, prob, context.directions, 8, context.membership, corner, "opencl")

    def mask(cells):
        return (cells[:, :1] + np.arange(gains.shape[1])[None]) % 3 == 0

    masked = np.where(mask(corner), gains, 0.0)
    for allowed, table in ((None, gains), (mask, masked)):
        flat = np.argsort(-table.ravel(), kind="stable")[:5]
        got = search_views(state, prob, corner, context, "prob", 5, view_mask=allowed)
        assert [(tuple(c.cell), c.view_index) for c in got] == [
            (tuple(corner[i // table.shape[1]]), int(i % table.shape[1])) for i in flat
        ]
        np.testing.assert_allclose([c.gain for c in got], table.ravel()[flat], rtol=1e-6)
    best = search_views(state, prob, corner, context, "prob", 1)[0]
    first = int(np.argmax(gains))
    assert (tuple(best.cell), best.view_index) == (tuple(corner[first // gains.shape[1]]), first % gains.shape[1])


@pytest.mark.parametrize("reach", [1, 3, 9])
def test_origins_near_unknown_keep_every_origin_within_reach(rng, reach):
    """The block test keeps every origin the cell-exact band keeps, and none farther than reach + block."""
    from nbv_prob_cnn.planners.candidates import near_unknown_origins

    state = _state(rng, (37, 30, 21), 0.0)
    state[5:7, 22:25, 3:5] = -1
    origins = empty_origins(state)
    distance = ndimage.distance_transform_cdt(state != -1, metric="chessboard")[tuple(origins.T)]
    kept = near_unknown_origins(state, origins, reach)
    assert {tuple(c) for c in origins[distance <= reach]} <= {tuple(c) for c in kept}
    kept_distance = ndimage.distance_transform_cdt(state != -1, metric="chessboard")[tuple(kept.T)]
    assert kept_distance.max() < reach + 2 * 4 and kept.shape[0] < origins.shape[0]
    assert np.all(np.diff(np.ravel_multi_index(tuple(kept.T), state.shape)) > 0)  # order kept


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_empty_origins_of_a_region_are_the_grids_cut_to_it(rng, stride):
    """Listing a box's empty cells gives the whole grid's list cut to the box, in the same order, on the
    grid's lattice (boxes off the lattice, partly outside the grid, thinner than the stride)."""
    state = _state(rng, (23, 19, 14), 0.2)
    every = empty_origins(state, stride)
    for lo, hi in [
        ((0, 0, 0), (23, 19, 14)),
        ((1, 2, 3), (20, 7, 11)),
        ((-4, 5, 5), (9, 40, 6)),
        ((5, 5, 5), (6, 6, 6)),
    ]:
        inside = np.all((every >= np.maximum(lo, 0)) & (every < np.array(hi)), axis=1)
        np.testing.assert_array_equal(empty_origins(state, stride, (lo, hi)), every[inside])
    flat = _state(rng, (30, 17), 0.2)
    every = empty_origins(flat, stride)
    inside = np.all((every >= [3, 4]) & (every < [25, 11]), axis=1)
    np.testing.assert_array_equal(empty_origins(flat, stride, ((3, 4), (25, 11))), every[inside])
    with pytest.raises(ValueError, match="region"):
        empty_origins(state, stride, ((30, 0, 0), (40, 5, 5)))  # no cell of the grid
