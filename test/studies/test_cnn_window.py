"""The CNN window study (studies.cnn_window) on a corner of a 3DT state."""

from __future__ import annotations

import numpy as np

from studies.cnn_window import WindowScore, score_windows, summary, workspace


def test_a_window_that_covers_the_grid_ranks_as_the_whole_grid(rng) -> None:
    from nbv_prob_cnn.bench.scale import scale_state

    state = np.ascontiguousarray(scale_state((128, 128, 96), 1000)[32:96, 32:96, :48])
    scores = score_windows(state, 1000, margins=(0, 64), width=16)
    whole, small, covering = scores
    assert whole.margin == -1 and whole.window_cells == state.size
    assert small.window_cells == 16**3 and small.origins == whole.origins > 1
    assert -1.0 <= small.rho_views <= 1.0 and small.regret >= 0.0
    # margin 64 on a 64-cell grid: the window is the grid, the map the whole grid's (one CNN pass)
    assert covering.window_cells == state.size
    assert covering.rho_views == 1.0 and covering.same_best and covering.regret == 0.0


def test_the_workspace_is_centred_on_the_table_and_the_summary_averages() -> None:
    lo, hi = workspace((128, 128, 96), 32)
    assert list(lo) == [48, 48, 8] and list(hi) == [80, 80, 40]
    rows = [
        WindowScore(1, 16, 100, 50, 0.9, 0.8, True, 0.0, 0.5),
        WindowScore(2, 16, 100, 50, 0.7, 0.6, False, 0.2, 0.7),
    ]
    table = summary(rows).splitlines()
    assert table[2] == "| 16 | 100 | 0.800 | 0.700 | 1 / 2 | 0.100 / 0.200 | 0.60 |"
