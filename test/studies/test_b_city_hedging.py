"""The B-City-CNN hedging study (studies.b_city_hedging) by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nbv_prob_cnn.basics.datasets import dataset_spec
from nbv_prob_cnn.completion import city_cache
from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout

METHODS = ("flat_city_cnn", "b_city_cnn", "d_city_cnn")


def test_hedged_vectors_by_hand():
    """Two views with unit vectors (1, 0) and (0, 1), predicted gains 0.2 and 0.4 in one cell."""
    from studies.b_city_hedging import hedged_vectors

    flat = np.array([[0.2], [0.4]], np.float32)
    unit = np.array([[1.0, 0.0], [0.0, 1.0]], np.float32)
    np.testing.assert_allclose(hedged_vectors(flat, unit, 0.0)[:, 0], [0.0, 0.4])
    np.testing.assert_allclose(hedged_vectors(flat, unit, 1e9)[:, 0], [0.1, 0.2], rtol=1e-6)
    # temperature 0.2: softmax of (1, 2) = (0.26894, 0.73106)
    np.testing.assert_allclose(hedged_vectors(flat, unit, 0.2)[:, 0], [0.26894 * 0.2, 0.73106 * 0.4], rtol=1e-4)
    with pytest.raises(ValueError, match="temperature"):
        hedged_vectors(flat, unit, -1.0)


def test_hedging_tradeoff_of_a_flat_oracle(tiny_worlds):
    """A Flat network that outputs its own targets, decoded hard (k = 0), is the B target
    exactly: MSE 0 and cell ρ 1; hedged (k > 0), its vectors shrink: MSE above 0."""
    from studies.b_city_hedging import hedging_tradeoff

    spec = dataset_spec("2d")
    layout = CacheLayout.for_training("2d", 16, 24)
    city_cache.ensure_chunks(layout, {"eval": [100, 101]}, "numpy", progress=False)
    flat = list(CachedCityExamples("flat_city_cnn", layout, [], [100, 101], [], 16).fixed([100, 101]))
    b = list(CachedCityExamples("b_city_cnn", layout, [], [100, 101], [], 16).fixed([100, 101]))
    table = {e.inputs.tobytes(): e.target for e in flat}

    class Oracle(torch.nn.Module):
        def forward(self, x):
            return torch.as_tensor(table[x[0].numpy().tobytes()])[None]

    scores = hedging_tradeoff(spec, Oracle(), flat, b, np.zeros(2, np.float32), temperatures=(0.0, 10.0))
    by_k = {s.temperature: s for s in scores if s.name == "hedged Flat City-CNN"}
    assert by_k[0.0].mse == pytest.approx(0.0, abs=1e-12)
    assert by_k[0.0].cell_rho == pytest.approx(1.0, abs=1e-3)  # float32 norms part a few exact ties
    assert by_k[10.0].mse > 0.0
    zero = next(s for s in scores if s.name == "mean target")
    assert zero.mse == pytest.approx(np.mean([np.mean(e.target.astype(np.float64) ** 2) for e in b]), rel=1e-5)
