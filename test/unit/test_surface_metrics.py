"""Surface coverage, Chamfer distance and views to a coverage level, on hand-worked cases."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.exploration.surface_metrics import (
    SurfaceCoverage,
    chamfer_distance,
    free_space_of,
    sample_surface_points,
    surface_cells,
    surface_coverage,
    triangle_areas,
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


def test_triangle_areas_by_hand() -> None:
    vertices = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, 0.0], [2.0, 3.0, 0.0], [0.0, 0.0, 4.0]])
    # legs 2 and 3: 3; the other half of the 2 x 3 rectangle: 3; legs 2 and 4 in the xz plane: 4; a line: 0
    triangles = np.array([[0, 1, 2], [1, 3, 2], [0, 1, 4], [0, 1, 1]])
    np.testing.assert_allclose(triangle_areas(vertices, triangles), [3.0, 3.0, 4.0, 0.0])


def test_surface_points_lie_on_the_mesh_spread_by_area() -> None:
    # two triangles in z = 0 and z = 1, areas 0.5 and 1.5: a quarter of the points on the first
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [3, 0, 1], [0, 1, 1]], dtype=float)
    triangles = np.array([[0, 1, 2], [3, 4, 5]])
    points = sample_surface_points(vertices, triangles, 8000, np.random.default_rng(1))
    assert points.shape == (8000, 3)
    low = points[:, 2] == 0.0
    np.testing.assert_allclose(points[~low, 2], 1.0, atol=1e-12)  # the upper triangle's barycentric sum
    assert low.mean() == pytest.approx(0.25, abs=0.02)  # 5 standard errors of a binomial 8000 x 0.25
    # inside the triangles: x, y >= 0, x + y <= 1 (first) and x / 3 + y <= 1 (second)
    assert np.all(points[:, :2] >= 0.0)
    assert np.all(points[low, 0] + points[low, 1] <= 1.0 + 1e-12)
    assert np.all(points[~low, 0] / 3 + points[~low, 1] <= 1.0 + 1e-12)
    # uniform over the area: the centroid of the first triangle's points is its centroid (1/3, 1/3)
    np.testing.assert_allclose(points[low, :2].mean(axis=0), [1 / 3, 1 / 3], atol=0.02)
    same = sample_surface_points(vertices, triangles, 10, np.random.default_rng(1))
    np.testing.assert_array_equal(same, sample_surface_points(vertices, triangles, 10, np.random.default_rng(1)))
    assert sample_surface_points(vertices, np.array([[0, 1, 1]]), 5, np.random.default_rng(1)).shape == (0, 3)
    assert sample_surface_points(vertices, triangles, 0, np.random.default_rng(1)).shape == (0, 3)
    with pytest.raises(ValueError, match="out of range"):
        sample_surface_points(vertices, np.array([[0, 1, 6]]), 5, np.random.default_rng(1))


def two_rooms() -> np.ndarray:
    """A 2D map 5 × 7: a wall two cells thick (columns 3, 4) between room A (columns 0-2) and
    room B (columns 5, 6)."""
    truth = np.zeros((5, 7), np.uint8)
    truth[:, 3:5] = 1
    return truth


def test_the_surface_of_a_start_is_what_faces_its_free_space() -> None:
    truth = two_rooms()
    assert free_space_of(truth, (0, 0)).sum() == 15 and not free_space_of(truth, (0, 0))[:, 5:].any()
    expected = np.zeros(truth.shape, bool)
    expected[:, 3] = True  # room A sees column 3 only
    np.testing.assert_array_equal(surface_cells(truth, (4, 1)), expected)
    assert surface_cells(truth).sum() == 10 and surface_cells(truth, (2, 6))[:, 4].all()
    state = np.full(truth.shape, -1, np.int8)
    state[0, 3] = 1  # seen from room A: rows 0 and 1 of column 3, and (one cell off) of column 4
    assert surface_coverage(state, truth, (0, 0)) == pytest.approx(2 / 5)
    assert surface_coverage(state, truth) == pytest.approx(4 / 10)
    assert SurfaceCoverage.seen_from(truth, (0, 0))(state) == pytest.approx(2 / 5)
    assert SurfaceCoverage.seen_from(truth, (0, 3))(state) == pytest.approx(4 / 10)  # a start in the wall: all
    with pytest.raises(ValueError, match="is not empty"):
        free_space_of(truth, (0, 3))
    with pytest.raises(ValueError, match="no cell of the grid"):
        free_space_of(truth, (0, 7))


def test_the_underside_of_a_table_is_not_the_surface_seen_from_above() -> None:
    """A slab over the whole grid (z = 2, 3) closes off the gap below it (z = 0, 1), as 3DT's table."""
    truth = np.zeros((4, 4, 6), np.uint8)
    truth[:, :, 2:4] = 1
    assert surface_cells(truth).sum() == 32  # both faces of the slab
    above = surface_cells(truth, (1, 1, 5))
    assert above.sum() == 16 and above[:, :, 3].all()
    state = np.full(truth.shape, -1, np.int8)
    state[:, :, 3] = 1  # the top seen: the underside is within one cell of it
    assert surface_coverage(state, truth) == 1.0
    assert SurfaceCoverage.seen_from(truth, (1, 1, 5))(state) == 1.0
    below = SurfaceCoverage.seen_from(truth, (1, 1, 0))  # a run that starts in the gap
    assert below.surface_count == 16 and below.surface[:, :, 2].all()
    state[:, :, 3] = -1
    state[1, 1, 2] = 1  # one underside cell seen: its 3 x 3 of the 4 x 4 underside
    assert below(state) == pytest.approx(9 / 16)
