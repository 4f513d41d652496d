"""GridGeometry (nbv_prob_cnn.basics.geometry): a window of a grid has its cells where the grid has them."""

import numpy as np
import pytest

from nbv_prob_cnn.basics.geometry import GridGeometry


def test_a_window_puts_its_cells_where_the_grid_has_them():
    grid = GridGeometry((-1.0, 0.5, 2.0), 0.25, (40, 30, 20))
    window = grid.window((4, 6, 8), (10, 9, 7))
    assert window.shape == (10, 9, 7) and window.resolution == 0.25
    assert window.origin == (0.0, 2.0, 4.0)  # -1 + 4 x 0.25, 0.5 + 6 x 0.25, 2 + 8 x 0.25
    cells = np.array([[0, 0, 0], [9, 8, 6], [3, 2, 1]])
    np.testing.assert_allclose(window.cell_centre(cells), grid.cell_centre(cells + [4, 6, 8]))


def test_a_window_of_a_2d_grid_keeps_its_height():
    grid = GridGeometry((1.0, 2.0, 0.3), 0.5, (12, 10))
    window = grid.window((2, 3), (4, 4))
    assert window.origin == (2.0, 3.5, 0.3)
    np.testing.assert_allclose(window.cell_centre(np.array([[1, 1]])), grid.cell_centre(np.array([[3, 4]])))


def test_box_region_holds_every_cell_whose_centre_is_in_the_box():
    """Against the cell-by-cell test (cells_in_box) on random grids and boxes, some partly outside."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        shape = tuple(int(v) for v in rng.integers(1, 12, size=int(rng.integers(2, 4))))
        grid = GridGeometry(tuple(float(v) for v in rng.uniform(-2, 2, 3)), float(rng.uniform(0.05, 0.5)), shape)
        low = rng.uniform(-3, 3, 3)
        high = low + rng.uniform(0, 2, 3)
        cells = np.argwhere(np.ones(shape, dtype=bool))
        centred = grid.cells_in_box(cells, low, high)
        region = grid.box_region(low, high)
        if region is None:
            assert not centred.any()
            continue
        inside = np.all((cells >= region[0]) & (cells < np.array(region[1])), axis=1)
        assert not np.any(centred & ~inside)
        # at most one cell of slack per side beyond the centred cells' own box
        if centred.any():
            assert np.all(cells[centred].min(axis=0) - np.array(region[0]) <= 1)
            assert np.all(np.array(region[1]) - cells[centred].max(axis=0) <= 2)


def test_box_region_by_hand_and_its_bad_bounds():
    grid = GridGeometry((0.0, 0.0, 0.0), 0.5, (10, 10, 10))
    # centres 0.25, 0.75, ...: x in [1.0, 2.0] holds cells 2 and 3; one more cell each side
    assert grid.box_region([1.0, 0.0, 0.0], [2.0, 5.0, 0.3]) == ((1, 0, 0), (5, 10, 2))
    assert grid.box_region([10.0, 0.0, 0.0], [11.0, 1.0, 1.0]) is None  # beyond the grid
    with pytest.raises(ValueError, match="workspace"):
        grid.box_region([0.0, 0.0, float("nan")], [1.0, 1.0, 1.0])


def test_bad_placements_raise_naming_the_argument():
    # issue 48: a 2-coordinate origin and non-integer sizes were accepted
    with pytest.raises(ValueError, match="origin: expected 3 finite coordinates"):
        GridGeometry((0.5, -0.3), 0.0116, (64, 64))
    with pytest.raises(ValueError, match="origin"):
        GridGeometry((0.5, -0.3, float("nan")), 0.0116, (64, 64, 64))
    for shape in ((64.0, 64, 64), (64, 64, 64, 64), (64,), (0, 64), (True, 4)):
        with pytest.raises(ValueError, match="shape: expected 2 .* or 3 .* positive integer sizes"):
            GridGeometry((0.0, 0.0, 0.0), 0.0116, shape)
    with pytest.raises(ValueError, match="resolution"):
        GridGeometry((0.0, 0.0, 0.0), 0.0, (4, 4, 4))
    # a 2D grid keeps a 3D origin (its height), and numpy sizes are sizes
    assert GridGeometry((0.0, 0.0, 0.5), 0.1, (np.int64(4), 4)).dims == 2


def test_a_3d_view_on_a_2d_geometry_names_the_geometry():
    from nbv_prob_cnn.basics.view_pose import view_pose

    with pytest.raises(ValueError, match=r"geometry: shape \(64, 64\); a 3D grid needs a 3D geometry"):
        view_pose((1, 2, 3), 0, GridGeometry((0.0, 0.0, 0.0), 0.0116, (64, 64)))
