"""GridGeometry (nbv_prob_cnn.basics.geometry): a window of a grid has its cells where the grid has them."""

import numpy as np

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
