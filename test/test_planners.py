"""The view search: blocks of origins, ranking and ties."""

import numpy as np
import pytest

from nbv_prob_cnn.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.gain import ray_gains
from nbv_prob_cnn.grid import probability_with_constant
from nbv_prob_cnn.planners import PlanningContext, base, search_best_view
from nbv_prob_cnn.planners.base import search_views

SMALL_3D = DatasetDefaults("3du", 3, (18, 16, 14), 0.01, Sensor(60.0, 46.0, 8), 4, 3)


def _grid(rng):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=SMALL_3D.shape, p=[0.5, 0.45, 0.05])
    return state, probability_with_constant(state, 0.15)


def test_top_k_matches_brute_force_across_blocks(rng, monkeypatch):
    state, prob = _grid(rng)
    context = PlanningContext(SMALL_3D, backend="opencl")
    origins = np.argwhere(state == 0)
    full = ray_gains(state, prob, context.directions, 8, origins, "numpy") @ context.membership
    order = np.lexsort((np.arange(full.size), -full.ravel()))[:25]
    monkeypatch.setattr(base, "MAX_VIEWS_PER_CALL", 52 * 37)  # 37 origins per block: many blocks
    found = search_views(state, prob, origins, context, top_k=25)
    assert len(found) == 25
    np.testing.assert_allclose([f.gain for f in found], full.ravel()[order], atol=1e-5)
    flat = [i for i in order]
    got = [np.flatnonzero((origins == f.cell).all(axis=1))[0] * full.shape[1] + f.view_index for f in found]
    # same pairs (ties between equal gains may swap within float noise, so compare as sets)
    assert set(got) == set(flat)
    best = search_best_view(state, prob, origins, context)
    assert best.gain == found[0].gain


def test_no_view_when_nothing_unknown():
    state = np.zeros(SMALL_3D.shape, dtype=np.int8)
    context = PlanningContext(SMALL_3D)
    assert search_best_view(state, probability_with_constant(state, 0.15), np.argwhere(state == 0), context) is None


def test_cnn_methods_refuse_missing_weights(rng, monkeypatch, tmp_path):
    from nbv_prob_cnn.completion import WeightsError, inference
    from nbv_prob_cnn.planners import make_planner

    missing = tmp_path / "3du.pt"
    monkeypatch.setattr(inference, "default_weights_path", lambda dataset: missing)
    state, _ = _grid(rng)
    for method in ("cnn_prob", "cnn_prob_d"):
        with pytest.raises(WeightsError) as info:
            make_planner(method).plan(state, PlanningContext(SMALL_3D))
        assert str(missing) in str(info.value) and "nbv train --dataset 3du" in str(info.value)


def test_downsampled_method_evaluates_a_fixed_number_of_origins(rng):
    from nbv_prob_cnn.planners.methods import DOWNSAMPLED_ORIGINS, GAIN_METHODS, method_origins

    state = np.zeros((30, 30, 30), dtype=np.int8)
    context = PlanningContext(DatasetDefaults("3du", 3, (30, 30, 30), 0.01, Sensor(60.0, 46.0, 8), 4, 3))
    sub = method_origins(GAIN_METHODS["cnn_prob_d"], state, context)
    full = method_origins(GAIN_METHODS["cnn_prob"], state, context)
    assert sub.shape == (DOWNSAMPLED_ORIGINS[3], 3) == (500, 3) and full.shape[0] == 27000
    assert len({tuple(c) for c in sub}) == 500 and np.all(state[tuple(sub.T)] == 0)


def test_origin_stride_overrides_the_dataset(rng):
    state, _ = _grid(rng)
    every = PlanningContext(SMALL_3D, origin_stride=1).candidate_origins(state)
    np.testing.assert_array_equal(every, np.argwhere(state == 0))
    strided = PlanningContext(SMALL_3D, origin_stride=2).candidate_origins(state)
    assert strided.shape[0] < every.shape[0] and np.all(strided % 2 == 0)
    with pytest.raises(ValueError, match="origin_stride"):
        PlanningContext(SMALL_3D, origin_stride=0)
