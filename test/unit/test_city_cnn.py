"""City-CNN baselines: targets against hand-worked and independently computed omniscient gains,
network shapes and masks, decoding, and the planners."""

import math

import numpy as np
import pytest
import torch

from nbv_prob_cnn.basics.camera import Sensor, orientations
from nbv_prob_cnn.basics.datasets import DatasetSpec
from nbv_prob_cnn.gain import ray_directions
from nbv_prob_cnn.planners.city_cnn import (
    CityGeometry,
    boundary_subcells,
    build_network,
    city_targets,
    decode_views,
    encode_city_input,
    output_mask,
)

# 2D, range 3 cells, 4 sub-cells per side for every variant: 12 rays, small enough to work by hand.
TINY_2D = DatasetSpec("2d", 2, (8, 6), 1.0, Sensor(60.0, None, 3), 4, 2, city_n_rays=4)
TINY_3D = DatasetSpec("3du", 3, (10, 9, 8), 1.0, Sensor(60.0, 46.0, 4), 4, 2, city_n_rays=4)


def slow_observed_gain(state, truth, origin, direction, r_max):
    """Independent reference: walk the ray sample by sample; count the unknown cells it would
    observe (up to and including the first occupied one), weighted t^nu, over sum t^nu."""
    nu = state.ndim - 1
    seen = 0.0
    for t in range(r_max + 1):
        cell = tuple(int(math.floor(o + t * d + 0.5)) for o, d in zip(origin, direction, strict=True))
        if any(c < 0 or c >= n for c, n in zip(cell, state.shape, strict=True)) or state[cell] == 1:
            break
        if state[cell] == -1:
            seen += t**nu
            if truth[cell] == 1:
                break
    return seen / sum(t**nu for t in range(r_max + 1))


def test_subcells_follow_the_ray_order():
    for dims, n in ((2, 4), (2, 16), (3, 4)):
        sub = boundary_subcells(dims, n) + 0.5 - n / 2
        np.testing.assert_allclose(sub / np.linalg.norm(sub, axis=1, keepdims=True), ray_directions(dims, n))


def test_d_city_targets_by_hand():
    state = np.full((8, 6), -1, dtype=np.int8)
    state[1, 1] = 0  # the only known (empty) cell: the only origin
    truth = np.zeros((8, 6), dtype=np.uint8)
    truth[3, 2] = 1
    target = city_targets("d_city_cnn", state, truth, TINY_2D, backend="numpy")
    assert target.shape == (1, 32, 24)
    # sub-cell (3, 2) = direction (1.5, 0.5): samples (2, 1), (3, 2) = wall, stop -> (1 + 2) / (0+1+2+3)
    assert target[0, 4 + 3, 4 + 2] == pytest.approx(0.5)
    # sub-cell (3, 1) = (1.5, -0.5): (2, 1), (3, 0), (4, 0), all unknown and empty -> 6 / 6
    assert target[0, 4 + 3, 4 + 1] == pytest.approx(1.0)
    # sub-cell (0, 1) = (-1.5, -0.5): (0, 1), then (-1, 0) outside the grid -> 1 / 6
    assert target[0, 4 + 0, 4 + 1] == pytest.approx(1 / 6)
    assert np.all(target[0, 5:7, 5:7] == 0)  # central sub-cells
    assert np.count_nonzero(target[0, :4]) == 0 and np.count_nonzero(target[0, 8:]) == 0  # other cells


@pytest.mark.parametrize("spec", [TINY_2D, TINY_3D], ids=["2d", "3d"])
def test_targets_equal_omniscient_gains(rng, spec):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=spec.shape, p=[0.6, 0.35, 0.05])
    truth = np.where(state == -1, rng.random(spec.shape) < 0.2, state == 1).astype(np.uint8)
    geometry = CityGeometry.of("d_city_cnn", spec)
    origins = np.argwhere(state == 0)
    expected = np.array(
        [[slow_observed_gain(state, truth, o, d, spec.sensor.r_max) for d in geometry.directions] for o in origins]
    )
    target = city_targets("d_city_cnn", state, truth, spec, backend="numpy")[0]
    sub = boundary_subcells(spec.dims, 4)
    got = np.array([[target[tuple(o * 4 + s)] for s in sub] for o in origins])
    np.testing.assert_allclose(got, expected, atol=1e-5)
    views = expected @ geometry.membership  # view gains of the omniscient method
    flat = city_targets("flat_city_cnn", state, truth, spec, backend="numpy")
    np.testing.assert_allclose(flat[(slice(None), *origins.T)].T * geometry.view_scale, views, atol=1e-4)
    b = city_targets("b_city_cnn", state, truth, spec, backend="numpy")[(slice(None), *origins.T)].T
    np.testing.assert_allclose(np.linalg.norm(b, axis=1) * geometry.view_scale, views.max(axis=1), atol=1e-4)
    for method in ("flat_city_cnn", "d_city_cnn", "b_city_cnn"):  # a perfect network picks the oracle's view
        output = city_targets(method, state, truth, spec, backend="numpy")
        decoded = decode_views(method, output, state, spec, origins)
        assert decoded.max() == pytest.approx(views.max(), abs=1e-4)
        best = np.unravel_index(np.argmax(decoded), decoded.shape)
        assert views[best] == pytest.approx(views.max(), abs=1e-4)


def test_flat_target_by_hand():
    state = np.full((8, 6), -1, dtype=np.int8)
    state[1, 1] = 0
    truth = np.zeros((8, 6), dtype=np.uint8)
    truth[3, 2] = 1
    flat = city_targets("flat_city_cnn", state, truth, TINY_2D, backend="numpy")
    # view 0 looks along +x: rays (1.5, ±0.5) (18.4° off axis) only: 0.5 + 1.0; at most 3 rays per view
    assert CityGeometry.of("flat_city_cnn", TINY_2D).view_scale == 3
    assert flat[0, 1, 1] == pytest.approx(1.5 / 3)


def test_crops_and_3dt_lattice(rng):
    spec = DatasetSpec("3dt", 3, (32, 32, 24), 1.0, Sensor(60.0, 46.0, 6), 4, 4, city_output_stride=8)
    state = rng.choice(np.array([-1, 0], dtype=np.int8), size=spec.shape, p=[0.5, 0.5])
    truth = (rng.random(spec.shape) < 0.1).astype(np.uint8) * (state == -1)
    full = city_targets("flat_city_cnn", state, truth, spec, backend="numpy")
    assert full.shape == (52, 4, 4, 3)
    box = (slice(8, 24), slice(0, 16), slice(8, 24))
    part = city_targets("flat_city_cnn", state, truth, spec, box, backend="numpy")
    np.testing.assert_allclose(part, full[:, 1:3, 0:2, 1:3], atol=1e-6)
    with pytest.raises(ValueError, match="lattice"):
        city_targets("flat_city_cnn", state, truth, spec, (slice(1, 9),) * 3, backend="numpy")
    shapes = {"flat_city_cnn": (52, 4, 4, 3), "b_city_cnn": (4, 4, 4, 3), "d_city_cnn": (1, 16, 16, 12)}
    for method, shape in shapes.items():
        net = build_network(method, spec, first_channels=2)
        out = net(encode_city_input(state[None]))
        assert tuple(out.shape[1:]) == shape
        assert output_mask(CityGeometry.of(method, spec), state).shape == shape[1:]
        assert (len(net.decoder), len(net.extra)) == ((1, 2) if method == "d_city_cnn" else (1, 0))
    b = build_network("b_city_cnn", spec, first_channels=2)(encode_city_input(state[None]))
    assert torch.all(b.abs() <= 1)


def test_mask_zeroes_non_empty_cells_and_centres():
    state = np.full((8, 6), -1, dtype=np.int8)
    state[2, 3] = 0
    mask = output_mask(CityGeometry.of("d_city_cnn", TINY_2D), state)
    assert mask.shape == (32, 24) and mask.sum() == 12
    assert mask[8:12, 12:16].sum() == 12 and mask[9:11, 13:15].sum() == 0
    assert output_mask(CityGeometry.of("flat_city_cnn", TINY_2D), state).sum() == 1
    assert len(orientations(2)) == 60


def test_reliability_by_hand():
    from nbv_prob_cnn.completion.calibration import reliability

    table = reliability(np.array([0.05, 0.05, 0.95, 0.95]), np.array([0, 1, 1, 1]))
    assert table.counts[0] == 2 and table.counts[9] == 2 and table.counts[1:9].sum() == 0
    assert table.observed[0] == pytest.approx(0.5) and table.mean_predicted[9] == pytest.approx(0.95)
    assert table.ece == pytest.approx(0.5 * 0.45 + 0.5 * 0.05)
    assert reliability(np.array([1.0, 0.0]), np.array([1, 0])).ece == 0.0  # p = 1 falls in the last bin
    with pytest.raises(ValueError):
        reliability(np.array([1.5]), np.array([1]))


@pytest.fixture(scope="module")
def tiny_city_cache(tmp_path_factory):
    """One data cache for the three methods' tiny trainings: the same grids and seeds, so the
    simulated samples and the (method-independent) example chunks are made once, not per method."""
    return tmp_path_factory.mktemp("tiny_city_cache")


@pytest.mark.parametrize("method", ["flat_city_cnn", "b_city_cnn", "d_city_cnn"])
def test_train_and_plan_with_a_tiny_city_cnn(tmp_path, monkeypatch, method, tiny_city_cache):
    """`train --method` on tiny grids, then the registry planner uses the weights; missing
    weights name the training command."""
    from nbv_prob_cnn.completion import WeightsError, inference
    from nbv_prob_cnn.completion import data as data_mod
    from nbv_prob_cnn.completion.train import TrainConfig, train
    from nbv_prob_cnn.planners import PlanningContext, make_planner

    def boxes(dataset, seed):
        grid = np.zeros((40, 40), dtype=np.uint8)
        r = np.random.default_rng(seed)
        for x, y in r.integers(0, 34, size=(6, 2)):
            grid[x : x + 5, y : y + 4] = 1
        return grid, 1

    monkeypatch.setenv("NBV_CACHE_DIR", str(tiny_city_cache))
    monkeypatch.setattr(data_mod, "load_environment", boxes)
    monkeypatch.setattr(data_mod, "current_generator_version", lambda: 1)
    out = tmp_path / f"2d_{method}.pt"
    kwargs = {
        "n_train_envs": 2, "n_val_envs": 1, "n_test_envs": 1, "crop": 16, "test_crop": 24, "progress": False,
        "threads": 2,
    }  # fmt: skip
    result = train(TrainConfig("2d", 1, out, method=method, device="cpu", first_channels=2, backend="numpy", **kwargs))
    assert result.ece is None and np.isfinite(result.test_mse) and out.is_file()
    assert f"nbv train --dataset 2d --method {method} --epochs 1" in out.with_suffix(".md").read_text()

    monkeypatch.setattr(inference, "default_weights_path", lambda dataset, model="cnn_prob": out)
    truth, _ = boxes("2d", 7)
    state = np.full(truth.shape, -1, dtype=np.int8)
    state[5:30, 5:30] = truth[5:30, 5:30]
    context = PlanningContext.for_dataset("2d", backend="numpy")
    ranked = make_planner(method).rank(state, context, top_k=5)
    assert 1 <= len(ranked) <= 5 and all(state[tuple(c.cell)] == 0 for c in ranked)
    gains = [c.gain for c in ranked]
    assert gains == sorted(gains, reverse=True) and gains[-1] > 0
    from nbv_prob_cnn.planners.city_cnn import predict

    origins = np.argwhere(state == 0)
    assert gains[0] == pytest.approx(
        decode_views(method, predict(method, state, context), state, context.defaults, origins).max()
    )

    monkeypatch.setattr(inference, "default_weights_path", lambda dataset, model="cnn_prob": tmp_path / "none.pt")
    with pytest.raises(WeightsError, match=f"nbv train --dataset 2d --method {method}"):
        make_planner(method).plan(state, context)


@pytest.mark.parametrize("method", ["flat_city_cnn", "b_city_cnn", "d_city_cnn"])
def test_city_networks_learn_a_tiny_dataset(rng, method):
    """A few hundred steps on four tiny grids bring the masked MSE well below that of the
    all-zero output (the trivial solution a sparse target invites)."""
    from nbv_prob_cnn.completion.tasks import TrainingTask
    from nbv_prob_cnn.completion.train_steps import train_step

    torch.manual_seed(0)
    spec = DatasetSpec("2d", 2, (32, 32), 1.0, Sensor(60.0, None, 12), 4, 2, city_n_rays=4)
    task = TrainingTask(method, spec, "numpy")
    examples = []
    for _ in range(4):
        truth = np.zeros((32, 32), dtype=np.uint8)
        for x, y in rng.integers(0, 28, size=(4, 2)):
            truth[x : x + 4, y : y + 3] = 1
        state = np.full((32, 32), -1, dtype=np.int8)
        state[4:20, 4:20] = truth[4:20, 4:20]
        examples.append(task.example(state, truth, (slice(0, 32), slice(0, 32))))
    zero_output = float(np.mean([np.mean(e.target**2) for e in examples]))
    model = task.build(8)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny tensors: threads only add overhead on a busy machine
    try:
        losses = [train_step(model, optimizer, examples, torch.device("cpu"))]
        while len(losses) < 400 and losses[-1] >= zero_output / 3:  # bounded
            losses.append(train_step(model, optimizer, examples, torch.device("cpu")))
    finally:
        torch.set_num_threads(threads)
    assert losses[-1] < zero_output / 3, (zero_output, losses[0], losses[-1], len(losses))


def test_frontier_is_unknown_next_to_empty_by_a_face():
    from nbv_prob_cnn.basics.grid import frontier_mask

    state = np.array([[-1, -1, -1, -1], [-1, 0, -1, 1], [-1, -1, 1, -1]], dtype=np.int8)
    expected = np.array([[0, 1, 0, 0], [1, 0, 1, 0], [0, 1, 0, 0]], dtype=bool)
    np.testing.assert_array_equal(frontier_mask(state), expected)


@pytest.mark.parametrize("method", ["flat_city_cnn", "d_city_cnn"])
def test_untrained_gain_heads_start_near_the_typical_gain(method):
    """The sigmoid gain heads start near the mean gain target (~0.1), not at 0.5: from 0.5 the
    first Adam steps drove a 2D D-City-CNN into a saturated all-zero output (its validation MSE
    then equalled the all-zero output's to six digits)."""
    from nbv_prob_cnn.planners.city_cnn import build_network

    torch.manual_seed(0)
    spec = DatasetSpec("2d", 2, (32, 32), 1.0, Sensor(60.0, None, 12), 4, 2, city_n_rays=4)
    state = np.full((32, 32), -1, dtype=np.int8)
    state[8:24, 8:24] = 0
    with torch.inference_mode():
        out = build_network(method, spec, 8)(encode_city_input(state[None])).numpy()
    assert 0.03 < out.mean() < 0.25, out.mean()


def test_zero_output_mse_by_hand():
    from nbv_prob_cnn.completion.tasks import Example
    from nbv_prob_cnn.completion.train_steps import zero_output_mse

    inputs, mask = np.zeros((2, 2, 2), np.float32), np.ones((1, 2, 2), np.float32)
    one_cell = Example(inputs, np.array([[[2.0, 0.0], [0.0, 0.0]]], np.float32), mask)  # (4 + 0 + 0 + 0) / 4 = 1
    halves = Example(inputs, np.full((1, 2, 2), 0.5, np.float32), mask)  # 0.25
    assert zero_output_mse([one_cell, halves]) == pytest.approx(0.625)
    assert math.isnan(zero_output_mse([]))


def test_gain_head_starts_at_the_mean_masked_target():
    """By hand: targets 0.2 and 0.0 on kept cells (0.9 on a masked one is ignored): mean 0.1."""
    from nbv_prob_cnn.completion.tasks import Example
    from nbv_prob_cnn.completion.train_steps import mean_masked_target, start_at_mean_target
    from nbv_prob_cnn.planners.city_cnn import build_network

    inputs = np.zeros((2, 1, 3), np.float32)
    example = Example(inputs, np.array([[[0.2, 0.0, 0.9]]], np.float32), np.array([[[1.0, 1.0, 0.0]]], np.float32))
    assert mean_masked_target([example]) == pytest.approx(0.1)
    spec = DatasetSpec("2d", 2, (32, 32), 1.0, Sensor(60.0, None, 12), 4, 2, city_n_rays=4)
    net = build_network("flat_city_cnn", spec, 4)
    start_at_mean_target(net, [example])
    assert torch.sigmoid(net.final.bias).detach().numpy() == pytest.approx(np.full(net.out_channels, 0.1), rel=1e-5)


def test_training_task_inputs_by_hand():
    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.tasks import TrainingTask

    # rows: empty, unknown, occupied / unknown, unknown, unknown (E=0, U=-1, O=1)
    state = np.array([[0, -1, 1], [-1, -1, -1]], dtype=np.int8)
    completion = TrainingTask("cnn_prob", dataset_spec("2d")).encode(state[None])[0].numpy()
    assert completion.tolist() == [[[1, 0, 0], [0, 0, 0]], [[0, 0, 1], [0, 0, 0]]]  # E, O
    for model in ("flat_city_cnn", "b_city_cnn", "d_city_cnn"):
        city = TrainingTask(model, dataset_spec("2d")).encode(state[None])[0].numpy()
        # E, and F: the unknown face neighbours of the one empty cell
        assert city.tolist() == [[[1, 0, 0], [0, 0, 0]], [[0, 1, 0], [1, 0, 0]]], model
