"""The ternary grid's helpers (``basics/grid.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN, probability_with_constant


def test_probability_with_constant_by_hand():
    state = np.array([[UNKNOWN, EMPTY], [OCCUPIED, UNKNOWN]], dtype=np.int8)
    np.testing.assert_array_equal(probability_with_constant(state, 0.25), [[0.25, 0.0], [1.0, 0.25]])
    for p0 in (0.0, 1.0):  # the ends are probabilities too
        assert probability_with_constant(state, p0).dtype == np.float32


@pytest.mark.parametrize("p0", [1.5, -0.3, float("nan"), float("inf")])
def test_probability_with_constant_refuses_what_is_not_a_probability(p0):
    # issue 48: 1.5 and -0.3 went into the map
    with pytest.raises(ValueError, match=r"p0: expected a probability in \[0, 1\]"):
        probability_with_constant(np.full((2, 2), UNKNOWN, np.int8), p0)
