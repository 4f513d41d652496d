"""Surface coverage, Chamfer distance and views to a coverage level, on hand-worked cases."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.exploration.surface_metrics import (
    chamfer_distance,
    surface_cells,
    surface_coverage,
    views_to_coverage,
)


def wall_world() -> np.ndarray:
    """A 2D map 6 × 5: a solid block in columns 3..5 of every row; only column 3 faces free space."""
    truth = np.zeros((6, 5), np.uint8)
    truth[:, 3:] = 1
    return truth


def test_surface_is_the_occupied_cells_facing_free_space() -> None:
    surface = surface_cells(wall_world())
    expected = np.zeros((6, 5), bool)
    expected[:, 3] = True  # column 4 is occupied but faces only occupied cells and the grid's edge
    np.testing.assert_array_equal(surface, expected)


def test_coverage_counts_surface_cells_within_one_cell_of_a_seen_occupied_cell() -> None:
    truth = wall_world()
    state = np.full(truth.shape, -1, np.int8)
    assert surface_coverage(state, truth) == 0.0
    state[0, 3] = 1  # covers surface rows 0 and 1 (row 1 is one cell away)
    assert surface_coverage(state, truth) == pytest.approx(2 / 6)
    state[3, 4] = 1  # one cell behind the surface: covers rows 2, 3, 4 of column 3 diagonally / beside
    assert surface_coverage(state, truth) == pytest.approx(5 / 6)
    state[5, 2] = 1  # a cell seen occupied in front of the surface (noise) covers rows 4 and 5
    assert surface_coverage(state, truth) == pytest.approx(1.0)
    state[:] = 0  # seen empty everywhere: nothing covered
    assert surface_coverage(state, truth) == 0.0


def test_coverage_in_3d_and_without_surface() -> None:
    truth = np.zeros((4, 4, 4), np.uint8)
    truth[1:3, 1:3, 1:3] = 1  # a 2×2×2 cube, every cell on the surface
    assert surface_cells(truth).sum() == 8
    state = np.full(truth.shape, -1, np.int8)
    state[1, 1, 1] = 1  # its 3×3×3 neighbourhood holds the whole cube
    assert surface_coverage(state, truth) == 1.0
    assert surface_coverage(state, np.zeros_like(truth)) == 1.0
    with pytest.raises(ValueError, match="state: shape"):
        surface_coverage(state[:2], truth)


def test_chamfer_distance_by_hand() -> None:
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    b = np.array([[0.0, 0.0, 0.0]])
    # a -> b: 0 and 1 (mean 0.5); b -> a: 0 (mean 0); symmetric: 0.25
    assert chamfer_distance(a, b) == pytest.approx(0.25)
    assert chamfer_distance(a, a) == 0.0
    shifted = a + [0.0, 0.3, 0.4]  # every point 0.5 from its counterpart, and from nothing closer
    assert chamfer_distance(a, shifted) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="b: expected a non-empty"):
        chamfer_distance(a, np.zeros((0, 3)))
    with pytest.raises(ValueError, match="a: points must be finite"):
        chamfer_distance(np.array([[np.nan, 0.0, 0.0]]), b)


def test_views_to_coverage() -> None:
    assert views_to_coverage([0.5, 0.79, 0.85, 0.91, 0.93]) == {0.8: 3, 0.9: 4, 0.95: None}
    assert views_to_coverage([0.96], levels=(0.9,)) == {0.9: 1}
