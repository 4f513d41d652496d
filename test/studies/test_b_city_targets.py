"""The B-City-CNN target study (studies.b_city_targets) on hand-built targets."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("scipy")

from studies.b_city_targets import grid_agreement, neighbourhood_mean, tied_view_norms  # noqa: E402


def test_neighbourhood_mean_counts_only_kept_cells() -> None:
    values = np.arange(9, dtype=np.float64).reshape(1, 3, 3)
    keep = np.zeros((3, 3), dtype=bool)
    keep[0, 0] = keep[2, 2] = True
    mean = neighbourhood_mean(values, keep)[0]
    assert mean[1, 1] == pytest.approx((0 + 8) / 2)  # both kept cells are its neighbours
    assert mean[0, 0] == pytest.approx(0.0) and mean[0, 1] == pytest.approx(0.0)  # only (0, 0) near
    assert mean[2, 1] == pytest.approx(8.0)
    assert mean[0, 2] == pytest.approx(0.0)  # no kept neighbour: 0


def test_one_direction_keeps_the_ranking_and_alternating_ones_lose_it() -> None:
    x = np.arange(12, dtype=np.float64)
    gain = np.broadcast_to(0.1 + x[:, None] / 12.0, (12, 12)).copy()  # grows along x
    empty = np.ones((12, 12), dtype=bool)
    same = np.stack([gain, np.zeros_like(gain)])  # every best view along +x
    local, consistency, flat = grid_agreement(same, empty)
    assert local == pytest.approx(flat) and local > 0.9
    assert np.isnan(consistency)  # every neighbourhood agrees fully: nothing to rank
    # the upper half of the gains points +x / -x in a checkerboard: local means cancel there
    sign = np.where((np.indices((12, 12)).sum(axis=0) % 2 == 0) | (x[:, None] < 6), 1.0, -1.0)
    mixed = np.stack([gain * sign, np.zeros_like(gain)])
    local, consistency, flat_mixed = grid_agreement(mixed, empty)
    assert flat_mixed == pytest.approx(flat)  # the gains themselves are the same
    assert local < 0.0 and consistency < -0.5


def test_tied_views_shrink_the_mean_vector_by_their_spread() -> None:
    unit = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])  # +x, +y, -x
    gains = np.array(
        [
            [0.8, 0.1, 0.1],  # one clear best view: norm = gain
            [0.5, 0.49, 0.0],  # +x and +y tied within 5 %: |(0.5, 0.5)| * 0.5
            [0.4, 0.0, 0.39],  # +x and -x tied: the directions cancel
            [0.0, 0.0, 0.0],  # no gain: no tied view
        ]
    )
    norm, count = tied_view_norms(gains, unit, 0.05)
    assert count.tolist() == [1, 2, 2, 0]
    assert norm == pytest.approx([0.8, 0.5 * np.sqrt(0.5), 0.0, 0.0])
    norm, count = tied_view_norms(gains, unit, 0.0)  # exact ties only
    assert count.tolist() == [1, 1, 1, 0] and norm == pytest.approx([0.8, 0.5, 0.4, 0.0])
