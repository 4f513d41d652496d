"""The view search: blocks of origins, ranking and ties."""

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.gain import ray_gains
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
    flat = list(order)
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

    missing = tmp_path / "3du_cnn_prob.pt"
    monkeypatch.setattr(inference, "default_weights_path", lambda dataset, model="cnn_prob": missing)
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


def test_registry_is_the_one_list_of_methods():
    from nbv_prob_cnn.planners import METHODS, PLANNER_FACTORIES, make_planner, ros_method
    from nbv_prob_cnn.planners.registry import PAPER_METHODS

    paper = {"random", "ig", "prob_ig", "cnn_prob", "cnn_prob_d", "omniscient"}
    paper |= {"flat_city_cnn", "b_city_cnn", "d_city_cnn"}
    ours = {"cnn_surface", "prob_surface", "omniscient_surface"}
    ours |= {"occlusion_aware", "unobserved_voxel", "rear_side_voxel", "proximity_count", "average_entropy"}
    assert set(METHODS) == paper | ours == set(PLANNER_FACTORIES) and set(PAPER_METHODS) == paper
    assert all(make_planner(name).name == name for name in METHODS)
    assert [n for n, s in METHODS.items() if s.needs_ground_truth] == ["omniscient", "omniscient_surface"]
    assert METHODS["cnn_prob_d"].weights == "cnn_prob" and METHODS["prob_ig"].weights is None
    assert ros_method("", "prob").name == "cnn_prob" and ros_method("d_city_cnn", "ig").name == "d_city_cnn"
    with pytest.raises(ValueError, match="unknown method 'omniscient'"):
        ros_method("omniscient", "ig")


@pytest.mark.parametrize("method", ["cnn_prob", "cnn_prob_d", "prob_ig"])
def test_remote_hooks_give_the_core_result(rng, method):
    """The ROS path (completion and ranking hooks, the gain server's function) equals the core path."""
    from nbv_prob_cnn.planners import make_planner
    from nbv_prob_cnn.planners.requests import rank_for_request

    spec = DatasetDefaults("3du", 3, (30, 30, 30), 0.01, Sensor(60.0, 46.0, 6), 4, 3)
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=spec.shape, p=[0.3, 0.69, 0.01])
    fake_cnn = rng.uniform(0.0, 1.0, spec.shape).astype(np.float32)
    completion = lambda s, c: np.where(s == -1, fake_cnn, (s == 1).astype(np.float32))  # noqa: E731
    box = lambda origins: origins[np.all(origins < 20, axis=1)]  # noqa: E731  (8000 cells > 500)
    local = PlanningContext(spec, rng=np.random.default_rng(5), backend="opencl", completion=completion)
    expected = make_planner(method).rank(state, local, 7, box)

    sent = []

    def ranker(name, grid, prob, top_k):
        sent.append((name, prob))
        server = PlanningContext(spec, rng=np.random.default_rng(5), backend="opencl")
        return rank_for_request(name, "ig", grid, server, top_k, box, prob)

    remote = PlanningContext(spec, backend="opencl", completion=completion, ranker=ranker)
    got = make_planner(method).rank(state, remote, 7, None)
    assert [(tuple(c.cell), c.view_index, c.gain) for c in got] == [
        (tuple(c.cell), c.view_index, c.gain) for c in expected
    ]
    assert all(np.all(c.cell < 20) for c in got) and len(got) == 7
    assert sent[0][0] == method and (sent[0][1] is None) == (method == "prob_ig")


def test_downsampled_origins_are_drawn_inside_the_filter():
    from nbv_prob_cnn.planners.methods import GAIN_METHODS, method_origins

    state = np.zeros((30, 30, 30), dtype=np.int8)
    context = PlanningContext(DatasetDefaults("3du", 3, (30, 30, 30), 0.01, Sensor(60.0, 46.0, 8), 4, 3))
    kept = method_origins(GAIN_METHODS["cnn_prob_d"], state, context, lambda o: o[o[:, 0] < 10])
    assert kept.shape == (500, 3) and np.all(kept[:, 0] < 10)


def test_origin_stride_overrides_the_dataset(rng):
    state, _ = _grid(rng)
    every = PlanningContext(SMALL_3D, origin_stride=1).candidate_origins(state)
    np.testing.assert_array_equal(every, np.argwhere(state == 0))
    strided = PlanningContext(SMALL_3D, origin_stride=2).candidate_origins(state)
    assert strided.shape[0] < every.shape[0] and np.all(strided % 2 == 0)
    with pytest.raises(ValueError, match="origin_stride"):
        PlanningContext(SMALL_3D, origin_stride=0)


def test_top_k_with_a_view_mask_returns_only_the_positive_views_best_first(rng):
    """Most views masked out (as by the arm's capability map): the top-k selection runs over the
    positive gains only; with fewer of them than top_k, every one comes back, best first, as a
    brute-force sort of the masked gains gives them."""
    state, prob = _grid(rng)
    context = PlanningContext(SMALL_3D, backend="opencl")
    origins = np.argwhere(state == 0)
    full = ray_gains(state, prob, context.directions, 8, origins, "numpy") @ context.membership
    allowed = rng.random(full.shape) < 0.002
    masked = np.where(allowed, full, 0.0).ravel()
    positive = np.flatnonzero(masked > 0)
    assert 5 < positive.size < 400
    found = search_views(state, prob, origins, context, top_k=400, view_mask=lambda chunk: allowed)
    assert len(found) == positive.size
    expected = positive[np.lexsort((positive, -masked[positive]))]
    np.testing.assert_allclose([f.gain for f in found], masked[expected], atol=1e-5)
    got = {int(np.flatnonzero((origins == f.cell).all(axis=1))[0]) * full.shape[1] + f.view_index for f in found}
    assert got == set(positive.tolist())
    few = search_views(state, prob, origins, context, top_k=5, view_mask=lambda chunk: allowed)
    np.testing.assert_allclose([f.gain for f in few], masked[expected[:5]], atol=1e-5)
