"""Cached City-CNN training sets (issue #21): a cached example equals the one ray-cast on the fly
for the same seed, generation resumes by skipping whole chunks, bad chunks give clear errors, a
cached training step never ray-casts, and the scores (mean-target MSE, Spearman ρ) by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nbv_prob_cnn.basics.datasets import dataset_spec
from nbv_prob_cnn.completion import city_cache
from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout, ChunkReader, CityCacheError
from nbv_prob_cnn.completion.data import crop_box, load_or_generate_sample, rotations
from nbv_prob_cnn.completion.tasks import Example, TrainingTask

METHODS = ("flat_city_cnn", "b_city_cnn", "d_city_cnn")


def _assert_same(cached: Example, reference: Example) -> None:
    np.testing.assert_array_equal(cached.inputs, reference.inputs)
    np.testing.assert_array_equal(cached.mask, reference.mask)
    np.testing.assert_array_equal(cached.target, reference.target)


def test_cached_2d_examples_equal_the_ones_ray_cast_on_the_fly(tiny_worlds):
    spec = dataset_spec("2d")
    layout = CacheLayout.for_training("2d", 16, 24)
    assert (layout.region, layout.crops_per_rotation) == (16, city_cache.CROPS_PER_ROTATION)
    assert city_cache.ensure_chunks(layout, {"train": [3], "eval": [101]}, "numpy", progress=False) == (2, 0)
    reader = ChunkReader(layout)
    assert reader.n_entries(3, "train") == 4 * city_cache.CROPS_PER_ROTATION
    sample = load_or_generate_sample("2d", 3)
    rots = rotations("2d")
    for entry in range(reader.n_entries(3, "train")):
        region = reader.read(3, "train", entry)
        rot = rots[region.rotation]
        box = tuple(slice(s, s + n) for s, n in zip(region.start, region.empty.shape, strict=True))
        assert region.empty.shape == (16, 16) and region.rotation == entry // city_cache.CROPS_PER_ROTATION
        for method in METHODS:  # the independent path: ray-cast the rotated grid's crop now
            reference = TrainingTask(method, spec, "numpy").example(
                rot.apply(sample.state), rot.apply(sample.truth), box
            )
            _assert_same(region.example(method, spec), reference)
    # validation/test: the fixed crop of fixed_examples (seeded by the environment), unrotated
    from nbv_prob_cnn.completion.train_sources import fixed_examples

    held_out = load_or_generate_sample("2d", 101)
    for method in METHODS:
        reference = fixed_examples(TrainingTask(method, spec, "numpy"), [held_out], 24)[0]
        _assert_same(reader.read(101, "eval", 0).example(method, spec), reference)


def test_cached_3d_crops_equal_the_on_the_fly_crops(tiny_worlds):
    """3D regions are whole rotated grids; a training crop is cut at read time with the same
    random box (8-cell lattice) the on-the-fly path draws from the same generator."""
    spec = dataset_spec("3dt")
    layout = CacheLayout.for_training("3dt", 16, None)
    assert layout.region is None and layout.crops_per_rotation == 1
    city_cache.ensure_chunks(layout, {"train": [5]}, "numpy", progress=False)
    sample = load_or_generate_sample("3dt", 5)
    rots = rotations("3dt")
    for method in METHODS:
        examples = CachedCityExamples(method, layout, [5], [], [], 16)
        task = TrainingTask(method, spec, "numpy")
        for k, rot in enumerate(rots):
            cached_rng, fly_rng = np.random.default_rng([k, 1]), np.random.default_rng([k, 1])
            cached = examples.train_example(0, k, cached_rng)
            state, truth = rot.apply(sample.state), rot.apply(sample.truth)
            box = crop_box(state.shape, 16, fly_rng, 8)
            assert cached is not None and cached.inputs.shape == (2, 16, 16, 16)
            _assert_same(cached, task.example(state, truth, box))
            # skipping an item (a data-parallel worker's) makes the same draws
            assert examples.train_example(0, k, cached_rng, build=False) is None
            crop_box(state.shape, 16, fly_rng, 8)
            assert cached_rng.integers(1 << 30) == fly_rng.integers(1 << 30)


def test_a_d_city_target_against_a_slow_walk(tiny_worlds):
    """Independent of the kernel: a cached D-City-CNN ray gain equals walking the ray cell by cell."""
    from test_city_cnn import slow_observed_gain

    from nbv_prob_cnn.gain import ray_directions

    spec = dataset_spec("2d")
    layout = CacheLayout.for_training("2d", 16, 24)
    city_cache.ensure_chunks(layout, {"train": [2]}, "numpy", progress=False)
    region = ChunkReader(layout).read(2, "train", 0)  # rotation 0: the grid as simulated
    sample = load_or_generate_sample("2d", 2)
    example = region.example("d_city_cnn", spec)
    n = spec.city_n_rays
    from nbv_prob_cnn.planners.city_cnn import boundary_subcells

    sub = boundary_subcells(2, n)
    directions = ray_directions(2, n)
    cells = np.argwhere(region.empty)
    assert cells.shape[0] > 0
    for cell in cells[:: max(1, cells.shape[0] // 5)]:
        origin = np.array(region.start) + cell
        for h in (0, len(sub) // 2, len(sub) - 1):
            expected = slow_observed_gain(sample.state, sample.truth, origin, directions[h], spec.sensor.r_max)
            got = example.target[0][tuple(cell * n + sub[h])]
            assert got == pytest.approx(expected, abs=1e-6), (cell, h)


def test_generation_resumes_by_skipping_whole_chunks(tiny_worlds, monkeypatch):
    layout = CacheLayout.for_training("2d", 16, 24)
    seeds = {"train": [0, 1], "eval": [100]}
    assert city_cache.ensure_chunks(layout, seeds, "numpy", progress=False) == (3, 0)
    kept = layout.chunk_path(0, "train")
    before = kept.stat().st_mtime_ns
    layout.chunk_path(1, "train").unlink()  # as if the job had stopped before this chunk
    made = []
    real = city_cache.generate_chunk
    monkeypatch.setattr(city_cache, "generate_chunk", lambda *a, **k: made.append(a[1:3]) or real(*a, **k))
    assert city_cache.ensure_chunks(layout, seeds, "numpy", progress=False) == (1, 2)
    assert made == [(1, "train")] and kept.stat().st_mtime_ns == before
    assert not list(layout.directory().glob(".*tmp*"))  # written via a temporary file, renamed
    assert city_cache.ensure_chunks(layout, seeds, "numpy", progress=False, share=(1, 2)) == (0, 3)


def test_missing_or_corrupt_chunks_give_clear_errors(tiny_worlds):
    layout = CacheLayout.for_training("2d", 16, 24)
    reader = ChunkReader(layout)
    with pytest.raises(CityCacheError, match=r"missing City-CNN example chunk of 2d seed 7 \(train\)"):
        reader.read(7, "train", 0)
    city_cache.ensure_chunks(layout, {"train": [7, 8]}, "numpy", progress=False)
    path = layout.chunk_path(7, "train")
    path.write_bytes(path.read_bytes()[:200])  # truncated
    with pytest.raises(CityCacheError, match=f"{path}: unreadable.*delete it to regenerate"):
        ChunkReader(layout).read(7, "train", 0)
    with pytest.raises(CityCacheError, match="no entry 99"):
        ChunkReader(layout).read(8, "train", 99)
    other = CacheLayout.for_training("2d", 16, None)  # another layout's file in this one's place
    other.directory().mkdir(parents=True, exist_ok=True)
    layout.chunk_path(8, "train").replace(other.chunk_path(8, "train"))
    ChunkReader(layout)  # nothing read yet
    with pytest.raises(CityCacheError, match="expected"):
        ChunkReader(other).read(8, "train", 0)


def test_cached_training_never_ray_casts_and_matches_the_on_the_fly_run(tiny_worlds, monkeypatch):
    """One epoch on 3D grids (crops cut from whole regions, so the same examples as on the fly):
    the same weights as the on-the-fly run; with the kernel disabled after the cache is made."""
    from nbv_prob_cnn.completion.train import TrainConfig, train
    from nbv_prob_cnn.planners import city_cnn

    kwargs = {
        "n_train_envs": 2, "n_val_envs": 1, "n_test_envs": 1, "crop": 16, "test_crop": None, "progress": False,
        "threads": 1, "device": "cpu", "first_channels": 2, "backend": "numpy", "batch_size": 2,
    }  # fmt: skip
    fly = train(TrainConfig("3dt", 1, tiny_worlds / "fly" / "w.pt", method="flat_city_cnn", cache=False, **kwargs))
    layout = CacheLayout.for_training("3dt", 16, None)
    city_cache.ensure_chunks(layout, {"train": [0, 1], "eval": [100, 120]}, "numpy", progress=False)

    def no_ray_casting(*args, **kw):
        raise AssertionError("a cached training step ray-cast")

    monkeypatch.setattr(city_cnn, "omniscient_ray_gains", no_ray_casting)
    cached = train(TrainConfig("3dt", 1, tiny_worlds / "cached" / "w.pt", method="flat_city_cnn", **kwargs))
    a = torch.load(tiny_worlds / "fly" / "w.last.ckpt", weights_only=True)["model"]
    b = torch.load(tiny_worlds / "cached" / "w.last.ckpt", weights_only=True)["model"]
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=1e-6, msg=key)
    assert cached.validation_mse == pytest.approx(fly.validation_mse, rel=1e-5)
    assert cached.test_rho == pytest.approx(fly.test_rho, abs=1e-6)
    card = (tiny_worlds / "cached" / "w.md").read_text()
    assert "mean training target" in card and "Spearman" in card and "cached v" in card


def test_warm_start_takes_over_weights_and_history_of_an_earlier_run(tiny_worlds):
    """A run that starts from another run's weights file (a new machine without its checkpoint):
    its history begins with the earlier run's epochs up to those weights, and with a negligible learning
    rate its weights stay the earlier ones exactly; a file of another architecture is refused."""
    import csv

    from nbv_prob_cnn.completion.train import TrainConfig, train

    kwargs = {
        "n_train_envs": 2, "n_val_envs": 1, "n_test_envs": 1, "crop": 16, "test_crop": None, "progress": False,
        "threads": 1, "device": "cpu", "first_channels": 2, "backend": "numpy", "batch_size": 2,
    }  # fmt: skip
    first = tiny_worlds / "first" / "w.pt"
    train(TrainConfig("3dt", 2, first, method="flat_city_cnn", **kwargs))
    payload = torch.load(first, weights_only=True)
    best_epoch = payload["card"]["best_epoch"]
    with open(first.with_suffix(".csv"), newline="") as fh:
        earlier = list(csv.DictReader(fh))[:best_epoch]
    second = tiny_worlds / "second" / "w.pt"
    train(TrainConfig("3dt", best_epoch + 1, second, method="flat_city_cnn", warm_start=first, lr=1e-30, **kwargs))
    with open(second.with_suffix(".csv"), newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == best_epoch + 1
    for old, new in zip(earlier, rows, strict=False):
        assert int(new["epoch"]) == int(old["epoch"])
        assert float(new["validation_mse"]) == pytest.approx(float(old["validation_mse"]), rel=1e-12)
    state = torch.load(second.with_name("w.last.ckpt"), weights_only=True)["model"]
    for key, value in payload["state_dict"].items():
        torch.testing.assert_close(state[key], value, rtol=0, atol=1e-12, msg=key)
    # the new epoch scored the same weights: the same validation MSE as the earlier run's best
    assert float(rows[-1]["validation_mse"]) == pytest.approx(float(earlier[-1]["validation_mse"]), rel=1e-5)
    assert f"Warm start at epoch {best_epoch} from w.pt" in second.with_suffix(".md").read_text()
    with pytest.raises(ValueError, match="architecture"):
        train(TrainConfig("3dt", 3, tiny_worlds / "third" / "w.pt", method="flat_city_cnn", warm_start=first,
              **{**kwargs, "first_channels": 3}))  # fmt: skip


def test_mean_target_and_spearman_by_hand():
    from nbv_prob_cnn.completion.city_scores import mean_target_per_channel, spearman

    inputs = np.zeros((2, 1, 3), np.float32)
    # channel 0: kept cells 0.2, 0.4 -> 0.3; channel 1: kept 1.0, 0.0 -> 0.5 (masked 0.9 ignored)
    target = np.array([[[0.2, 0.4, 0.9]], [[1.0, 0.0, 0.9]]], np.float32)
    example = Example(inputs, target, np.array([[[1.0, 1.0, 0.0]]], np.float32))
    np.testing.assert_allclose(mean_target_per_channel([example]), [0.3, 0.5], rtol=1e-6)
    assert spearman(np.array([1.0, 2.0, 3.0, 4.0]), np.array([10.0, 20.0, 25.0, 100.0])) == pytest.approx(1.0)
    assert spearman(np.array([1.0, 2.0, 3.0]), np.array([3.0, 2.0, 1.0])) == pytest.approx(-1.0)
    # ranks (1, 2, 3) vs (1, 3, 2): 1 - 6 * (0 + 1 + 1) / (3 * 8) = 0.5
    assert spearman(np.array([1.0, 2.0, 3.0]), np.array([1.0, 3.0, 2.0])) == pytest.approx(0.5)
    assert math.isnan(spearman(np.array([1.0, 1.0]), np.array([1.0, 2.0])))


def test_cell_rho_ranks_the_cells_by_their_best_view_only():
    """Three empty cells of a 2D Flat City-CNN output, hand-worked: the views inside each cell
    ranked right (so the pair ρ is high) but the cells' best views in the opposite order: cell
    ρ -1. B-City-CNN: the norms of the vectors, the same -1."""
    from nbv_prob_cnn.completion.city_scores import cell_gain_pairs, gain_pairs, spearman

    spec = dataset_spec("2d")
    inputs = np.zeros((2, 1, 3), np.float32)
    inputs[0] = 1.0  # all three cells empty
    mask = np.ones((1, 1, 3), np.float32)
    target = np.zeros((60, 1, 3), np.float32)
    output = np.zeros((60, 1, 3), np.float32)
    # best view gains (target): cell 0 0.2, cell 1 0.5, cell 2 0.1; each cell's second view half of it
    for cell, (best, predicted) in enumerate([(0.2, 0.3), (0.5, 0.1), (0.1, 0.6)]):
        target[cell, 0, cell], target[cell + 10, 0, cell] = best, best / 2
        output[cell, 0, cell], output[cell + 10, 0, cell] = predicted, predicted / 2
    example = Example(inputs, target, mask)
    predicted, truth = cell_gain_pairs("flat_city_cnn", spec, output, example)
    # ranks (2, 1, 3) against (2, 3, 1): 1 - 6 * (0 + 4 + 4) / (3 * 8) = -1
    assert spearman(predicted, truth) == pytest.approx(-1.0)
    assert spearman(*gain_pairs("flat_city_cnn", spec, output, example)) > 0.5
    b_target = np.zeros((2, 1, 3), np.float32)
    b_output = np.zeros((2, 1, 3), np.float32)
    b_target[:, 0, :] = [[0.2, 0.0, -0.1], [0.0, 0.5, 0.0]]  # norms 0.2, 0.5, 0.1
    b_output[:, 0, :] = [[0.0, 0.1, 0.0], [0.3, 0.0, -0.6]]  # norms 0.3, 0.1, 0.6
    predicted, truth = cell_gain_pairs("b_city_cnn", spec, b_output, Example(inputs, b_target, mask))
    assert spearman(predicted, truth) == pytest.approx(-1.0)


def test_scores_of_a_perfect_and_a_constant_predictor(tiny_worlds):
    """A network that outputs the target: MSE 0, ρ 1; the all-zero and mean-target MSEs by
    direct computation."""
    from nbv_prob_cnn.completion.city_scores import score_city

    spec = dataset_spec("2d")
    layout = CacheLayout.for_training("2d", 16, 24)
    city_cache.ensure_chunks(layout, {"eval": [100, 101]}, "numpy", progress=False)
    examples = CachedCityExamples("flat_city_cnn", layout, [], [100, 101], [], 16).fixed([100, 101])
    table = {e.inputs.tobytes(): e.target for e in examples}

    class Oracle(torch.nn.Module):
        def forward(self, x):
            return torch.as_tensor(table[x[0].numpy().tobytes()])[None]

    c = np.full(60, 0.05, np.float32)
    scores = score_city(Oracle(), "flat_city_cnn", spec, examples, c, torch.device("cpu"), 2)
    assert scores.mse == 0.0 and scores.rho == pytest.approx(1.0) and scores.n == 2
    assert scores.cell_rho == pytest.approx(1.0)
    assert scores.zero_mse == pytest.approx(np.mean([np.mean(e.target.astype(np.float64) ** 2) for e in examples]))
    expected = np.mean([np.mean((e.mask * 0.05 - e.target.astype(np.float64)) ** 2) for e in examples])
    assert scores.mean_mse == pytest.approx(expected, rel=1e-5)


def test_early_stopping_rule():
    from nbv_prob_cnn.completion.train import _stopped_early

    history = [{"epoch": e} for e in range(1, 6)]
    assert _stopped_early(history, {"epoch": 2}, 3)  # epochs 3, 4, 5 without a better one
    assert not _stopped_early(history, {"epoch": 3}, 3)
    assert not _stopped_early(history, {"epoch": 1}, None) and not _stopped_early([], {"epoch": 0}, 1)


def test_cli_city_options_and_paper_epochs():
    import argparse

    from nbv_prob_cnn.commands import train as cmd

    parser = argparse.ArgumentParser()
    cmd.add_arguments(parser)
    args = parser.parse_args(["--dataset", "3du", "--method", "d_city_cnn", "--ray", "--address", "h:6379",
                              "--workers", "4", "--patience", "5", "--no-cache"])  # fmt: skip
    assert (args.ray, args.address, args.workers, args.patience, args.no_cache) == (True, "h:6379", 4, 5, True)
    args = parser.parse_args(["--dataset", "3du"])
    assert (args.ray, args.address, args.patience, args.no_cache) == (False, None, None, False)
    # the paper: up to 120 epochs, 20 for 3DU/3DT B-City-CNN; cnn_prob keeps the data set's defaults
    assert [cmd.paper_epochs(d, "b_city_cnn") for d in ("2d", "3du", "3dt")] == [120, 20, 20]
    assert [cmd.paper_epochs(d, "d_city_cnn") for d in ("2d", "3du", "3dt")] == [120, 120, 120]
    assert cmd.paper_epochs("3du", "cnn_prob") == dataset_spec("3du").training.epochs
    with pytest.raises(SystemExit, match="--address needs --ray"):
        cmd.run(parser.parse_args(["--dataset", "3du", "--address", "h:1"]))


def test_a_2d_cache_needs_a_crop():
    with pytest.raises(ValueError, match="needs a training crop"):
        CacheLayout.for_training("2d", None, 400)
    assert CacheLayout.for_training("3du", None, None).name == "whole_evalwhole"


def test_cli_ray_path_calls_ray_train(monkeypatch, tmp_path):
    """`nbv train --ray --address A --workers N` hands the same arguments to Ray Train."""
    import argparse

    from nbv_prob_cnn.commands import train as cmd
    from nbv_prob_cnn.completion import ray_train
    from nbv_prob_cnn.completion.train import TrainResult

    calls = []

    def fake(config, **ray):
        calls.append((config, ray))
        return TrainResult(tmp_path / "w.pt", tmp_path / "l", tmp_path / "c", tmp_path / "p", tmp_path / "m", 0.1, 0.2,
                           None, config.epochs)  # fmt: skip

    monkeypatch.setattr(ray_train, "train_with_ray", fake)
    parser = argparse.ArgumentParser()
    cmd.add_arguments(parser)
    argv = ["--dataset", "3dt", "--method", "flat_city_cnn", "--ray", "--address", "h:6379", "--workers", "3"]
    assert cmd.run(parser.parse_args(argv)) == 0
    ((config, ray),) = calls
    assert (config.dataset, config.epochs, config.out) == ("3dt", 120, None)
    assert (ray["address"], config.workers, config.patience, config.crop) == ("h:6379", 3, 10, 64)
    assert config.cache is True and config.device is None
