"""Tests of the completion CNN: architecture, inference contract, weights, augmentation,
training data and a small end-to-end training run (all on tiny synthetic grids)."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import shutil

import numpy as np
import pytest
import torch
from torch import nn

from nbv_prob_cnn.basics.datasets import DATASET_SPECS, dataset_spec
from nbv_prob_cnn.basics.grid import UNKNOWN
from nbv_prob_cnn.completion import CompletionNet, WeightsError, complete, load_model, pad_to_multiple
from nbv_prob_cnn.completion import data as data_mod
from nbv_prob_cnn.completion.data import ROTATIONS, crop_box, rotations
from nbv_prob_cnn.completion.inference import save_weights
from nbv_prob_cnn.completion.model import encode_state
from nbv_prob_cnn.completion.tasks import TrainingTask
from nbv_prob_cnn.completion.train import TrainConfig, train
from nbv_prob_cnn.completion.train_files import side_paths
from nbv_prob_cnn.completion.train_steps import train_step

torch.set_num_threads(2)


def random_boxes(shape: tuple[int, ...], n: int, seed: int) -> np.ndarray:
    """A binary ground truth made of random axis-aligned boxes."""
    rng = np.random.default_rng(seed)
    truth = np.zeros(shape, dtype=np.uint8)
    for _ in range(n):
        lo = [int(rng.integers(0, s - 2)) for s in shape]
        box = tuple(slice(a, a + int(rng.integers(2, max(3, s // 3)))) for a, s in zip(lo, shape, strict=True))
        truth[box] = 1
    return truth


def partial_state(truth: np.ndarray, known_fraction: float, seed: int) -> np.ndarray:
    """The ground truth with a random subset of cells hidden as unknown."""
    rng = np.random.default_rng(seed)
    state = truth.astype(np.int8)
    state[rng.random(truth.shape) > known_fraction] = UNKNOWN
    return state


@pytest.fixture(scope="module")
def tiny2d() -> CompletionNet:
    torch.manual_seed(0)
    return CompletionNet(2, 2, 4).eval()


@pytest.fixture(scope="module")
def tiny3d() -> CompletionNet:
    torch.manual_seed(0)
    return CompletionNet(3, 2, 4).eval()


# --- shapes and padding -------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(13, 21), (16, 16), (1, 5)])
def test_output_shape_2d(tiny2d, shape):
    state = partial_state(random_boxes(shape, 3, 1) if min(shape) > 3 else np.zeros(shape, np.uint8), 0.5, 2)
    prob = complete(state, tiny2d, device="cpu")
    assert prob.shape == shape and prob.dtype == np.float32


@pytest.mark.parametrize("shape", [(9, 11, 7), (8, 8, 8)])
def test_output_shape_3d(tiny3d, shape):
    state = partial_state(random_boxes(shape, 3, 1), 0.5, 2)
    prob = complete(state, tiny3d, device="cpu")
    assert prob.shape == shape and prob.dtype == np.float32


def test_batch_shape(tiny3d):
    states = np.stack([partial_state(random_boxes((9, 10, 11), 3, s), 0.4, s) for s in range(3)])
    probs = complete(states, tiny3d, device="cpu", batch=True, chunk=2)
    assert probs.shape == states.shape
    np.testing.assert_allclose(probs[1], complete(states[1], tiny3d, device="cpu"), atol=1e-6)


def test_pad_to_multiple_round_trip():
    state = partial_state(random_boxes((13, 21, 5), 4, 3), 0.5, 4)
    padded = pad_to_multiple(state, 8)
    assert padded.shape == (16, 24, 8)
    crop = tuple(slice(0, s) for s in state.shape)
    np.testing.assert_array_equal(padded[crop], state)
    mask = np.ones(padded.shape, bool)
    mask[crop] = False
    assert np.all(padded[mask] == UNKNOWN)
    assert pad_to_multiple(padded, 8) is padded
    batch = pad_to_multiple(np.stack([state, state]), 8, n_spatial=3)
    assert batch.shape == (2, 16, 24, 8)


def test_internal_padding_matches_numpy_padding(tiny2d):
    state = partial_state(random_boxes((13, 21), 3, 5), 0.5, 6)
    direct = complete(state, tiny2d, device="cpu")
    padded = complete(pad_to_multiple(state, tiny2d.multiple), tiny2d, device="cpu")
    np.testing.assert_allclose(direct, padded[:13, :21], atol=1e-6)


@pytest.mark.parametrize(
    ("head", "out_channels", "removed", "extra"),
    [("completion", 1, 0, 0), ("sigmoid", 1, 0, 2), ("sigmoid", 4, 1, 0), ("tanh", 3, 0, 1)],
)
def test_inference_layout_matches_the_training_forward(head, out_channels, removed, extra):
    # without autograd the 3D deconvs and the 1x1 output run channels-last (a separate code path)
    torch.manual_seed(3)
    model = CompletionNet(3, 2, 4, out_channels=out_channels, head=head, removed_deconv=removed, extra_deconv=extra)
    for parameter in model.parameters():  # not the sigmoid's flat start: every channel counts
        torch.nn.init.normal_(parameter, std=0.3)
    model.eval()
    x = (torch.rand(2, 2, 12, 8, 9) < 0.4).float()
    with torch.enable_grad():
        tracked = model(x)
    assert tracked.requires_grad  # the plain layers ran
    reference = tracked.detach()
    with torch.inference_mode():
        fast = model(x)
    assert fast.shape == reference.shape == (2, out_channels, *model.output_shape((12, 8, 9)))
    assert float(reference.std()) > 1e-3
    torch.testing.assert_close(fast, reference, atol=1e-6, rtol=1e-5)


# --- the P = U·P' + O contract ---------------------------------------------------------------


@pytest.mark.parametrize("dims", [2, 3])
def test_known_cells_exact_unknown_in_unit_interval(tiny2d, tiny3d, dims):
    model = tiny2d if dims == 2 else tiny3d
    shape = (20, 18) if dims == 2 else (10, 9, 12)
    state = partial_state(random_boxes(shape, 4, 7), 0.5, 8)
    prob = complete(state, model, device="cpu")
    assert np.all(prob[state == 0] == 0.0)
    assert np.all(prob[state == 1] == 1.0)
    unknown = prob[state == UNKNOWN]
    assert unknown.size and np.all((unknown >= 0.0) & (unknown <= 1.0))
    # the model's own output (before the numpy clean-up) already obeys the contract
    with torch.inference_mode():
        raw_p = model(encode_state(state[None]))[0, 0].numpy()
    assert np.all(raw_p[state == 0] == 0.0) and np.all(raw_p[state == 1] == 1.0)


def test_gradient_zero_on_known_cells(tiny2d):
    model = CompletionNet(2, 2, 4)
    truth = random_boxes((16, 16), 4, 9)
    state = partial_state(truth, 0.5, 10)
    prob, raw = model(encode_state(state[None]), return_raw=True)
    raw.retain_grad()
    loss = nn.functional.mse_loss(prob, torch.as_tensor(truth[None, None], dtype=torch.float32))
    loss.backward()
    grad = raw.grad[0, 0].numpy()
    assert np.all(grad[state != UNKNOWN] == 0.0)
    assert np.any(grad[state == UNKNOWN] != 0.0)


# --- architecture -----------------------------------------------------------------------------


def test_architecture_3d_n3():
    model = CompletionNet(3, 3, 16)
    convs = [m for m in model.modules() if isinstance(m, nn.Conv3d)]
    deconvs = [m for m in model.modules() if isinstance(m, nn.ConvTranspose3d)]
    assert not any(isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)) for m in model.modules())
    assert len(convs) == 2 * 3 + 1 and len(deconvs) == 3
    enc = convs[:-1]
    assert [(c.in_channels, c.out_channels) for c in enc] == [(2, 16), (16, 16), (16, 32), (32, 32), (32, 64), (64, 64)]
    assert all(c.kernel_size == (3, 3, 3) and c.padding == (1, 1, 1) for c in enc)
    assert [c.stride for c in enc] == [(1, 1, 1), (2, 2, 2)] * 3
    # deconv blocks, deepest first: out channels halve block by block, inputs include the skips
    order = [model.decoder[i][0] for i in reversed(range(3))]
    assert [(d.in_channels, d.out_channels) for d in order] == [(64, 64), (64 + 32, 32), (32 + 16, 16)]
    assert all(d.kernel_size == (3, 3, 3) and d.stride == (2, 2, 2) for d in deconvs)
    assert all(d.padding == (1, 1, 1) and d.output_padding == (1, 1, 1) for d in deconvs)
    final = convs[-1]
    assert (final.in_channels, final.out_channels, final.kernel_size) == (16 + 2, 1, (1, 1, 1))
    assert sum(isinstance(m, nn.LeakyReLU) for m in model.modules()) == 2 * 3 + 3


def test_architecture_2d_uses_2d_layers():
    model = CompletionNet(2, 6, 8)
    convs = [m for m in model.modules() if isinstance(m, nn.Conv2d)]
    assert len(convs) == 13 and sum(isinstance(m, nn.ConvTranspose2d) for m in model.modules()) == 6
    assert convs[-2].out_channels == 8 * 2**5
    x = encode_state(np.full((1, 64, 64), UNKNOWN, np.int8))
    assert model(x).shape == (1, 1, 64, 64)


# --- training ---------------------------------------------------------------------------------


def test_tiny_model_overfits_tiny_dataset():
    torch.manual_seed(0)
    model = CompletionNet(2, 2, 8)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    truths = np.stack([random_boxes((16, 16), 5, s) for s in range(4)])
    states = np.stack([partial_state(t, 0.5, 100 + i) for i, t in enumerate(truths)])
    task = TrainingTask("cnn_prob", dataset_spec("2d"))
    box = (slice(0, 16), slice(0, 16))
    examples = [task.example(s, t, box) for s, t in zip(states, truths, strict=True)]
    losses = [train_step(model, optimizer, examples, torch.device("cpu"))]
    while len(losses) < 600 and losses[-1] >= losses[0] / 10:  # bounded: at most 600 steps
        losses.append(train_step(model, optimizer, examples, torch.device("cpu")))
    assert losses[-1] < losses[0] / 10, (losses[0], losses[-1], len(losses))


# --- weights ----------------------------------------------------------------------------------


def test_save_load_identical_output(tmp_path, tiny3d):
    path = save_weights(tiny3d, tmp_path / "w.pt", "3du", {"note": "test"})
    loaded = load_model(path, dataset="3du", device="cpu")
    assert loaded is not tiny3d and loaded.card == {"note": "test"}
    state = partial_state(random_boxes((12, 12, 12), 4, 11), 0.4, 12)
    np.testing.assert_array_equal(complete(state, loaded, device="cpu"), complete(state, tiny3d, device="cpu"))
    np.testing.assert_array_equal(complete(state, path, device="cpu"), complete(state, tiny3d, device="cpu"))
    assert load_model(path, device="cpu") is loaded  # cached per (file, device)


def test_missing_weights(tmp_path):
    path = tmp_path / "nowhere" / "3dt_cnn_prob.pt"
    with pytest.raises(WeightsError) as err:
        load_model(path)
    assert str(path) in str(err.value) and "nbv train --dataset 3dt" in str(err.value)
    assert isinstance(err.value, ValueError)


def test_incompatible_weights(tmp_path, tiny2d):
    path = save_weights(tiny2d, tmp_path / "w.pt", "2d")
    with pytest.raises(WeightsError, match="nbv train --dataset 3du"):
        load_model(path, dataset="3du", device="cpu")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a weights file")
    with pytest.raises(WeightsError, match="junk.pt"):
        load_model(junk, device="cpu")
    bad = tmp_path / "bad.pt"
    payload = torch.load(path, weights_only=True)
    payload["config"]["n_conv"] = 3
    torch.save(payload, bad)
    with pytest.raises(WeightsError, match="nbv train"):
        load_model(bad, device="cpu")
    with pytest.raises(ValueError, match="3D"):
        complete(np.zeros((4, 4, 4), np.int8), path, device="cpu")


# --- input validation -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "bad",
    [
        np.full((8, 8), 2, np.int8),
        np.full((8, 8), -2, np.int8),
        np.zeros((8, 8), np.float32),
        [[0, 1], [1, 0]],
        np.zeros(8, np.int8),
    ],
)
def test_bad_input(tiny2d, bad):
    with pytest.raises(ValueError, match="state"):
        complete(bad, tiny2d, device="cpu")


def test_bad_batch_input(tiny2d):
    with pytest.raises(ValueError, match="state"):
        complete(np.full((2, 8, 8), 3, np.int8), tiny2d, device="cpu", batch=True)
    with pytest.raises(ValueError, match="state"):
        complete(np.zeros((2, 8, 8), np.float64), tiny2d, device="cpu", batch=True)


def test_3d_without_model_needs_dataset():
    with pytest.raises(ValueError, match="dataset"):
        complete(np.zeros((4, 4, 4), np.int8))


# --- augmentation ---------------------------------------------------------------------------


@pytest.mark.parametrize(("dataset", "count"), [("2d", 4), ("3dt", 4), ("3du", 8)])
def test_rotations_distinct_bijections(dataset, count):
    rots = rotations(dataset)
    assert len(rots) == count and rots[0].k == 0
    shape = {"2d": (5, 5), "3dt": (5, 5, 3), "3du": (4, 4, 4)}[dataset]
    cells = np.arange(np.prod(shape)).reshape(shape)
    images = [r.apply(cells) for r in rots]
    for image, rot in zip(images, rots, strict=True):
        np.testing.assert_array_equal(np.sort(image, axis=None), cells.ravel())  # a permutation
        np.testing.assert_array_equal(rot.invert(image), cells)
        if dataset == "3dt":
            assert image.shape == shape  # rotations about z keep the table horizontal
            np.testing.assert_array_equal(np.sort(image[:, :, 0], axis=None), np.sort(cells[:, :, 0], axis=None))
    for i in range(count):
        for j in range(i + 1, count):
            assert not np.array_equal(images[i], images[j]), (rots[i].name, rots[j].name)


def test_3du_rotations_send_up_to_every_axis():
    ups = set()
    for rot in ROTATIONS["3du"]:
        marker = np.zeros((5, 5, 5), np.uint8)
        marker[2, 2, 4] = 1
        ups.add(tuple(np.argwhere(rot.apply(marker))[0] - 2))
    assert len(ups) == 6


@pytest.mark.parametrize("dataset", ["2d", "3du"])
def test_rotation_keeps_state_and_truth_consistent(dataset):
    shape = (12, 9) if dataset == "2d" else (8, 6, 7)
    truth = random_boxes(shape, 4, 13)
    state = partial_state(truth, 0.5, 14)
    for rot in rotations(dataset):
        s, t = rot.apply(state), rot.apply(truth)
        known = s != UNKNOWN
        np.testing.assert_array_equal(s[known], t[known])
        assert np.count_nonzero(known) == np.count_nonzero(state != UNKNOWN)
        batch = rot.apply(np.stack([state, state]), first_axis=1)
        np.testing.assert_array_equal(batch[1], s)


def test_crop_box():
    rng = np.random.default_rng(0)
    box = crop_box((100, 30), 40, rng)
    assert box[0].stop - box[0].start == 40 and (box[1].start, box[1].stop) == (0, 30)
    assert crop_box((5, 6), None, rng) == (slice(0, 5), slice(0, 6))


# --- training data --------------------------------------------------------------------------


def test_simulated_state_agrees_with_truth_3du():
    truth = random_boxes((24, 24, 24), 6, 15)
    rng = np.random.default_rng(0)
    state, positions, indices = data_mod.simulate_state(truth, "3du", rng)
    assert state.dtype == np.int8 and state.shape == truth.shape
    assert 10 <= len(positions) <= 15 and len(indices) == len(positions)
    known = state != UNKNOWN
    assert known.any() and (~known).any()
    np.testing.assert_array_equal(state[known], truth[known])
    assert np.all(truth[tuple(positions.T)] == 0)  # cameras in ground-truth-empty cells


def test_generate_sample_reproducible_2d():
    truth = random_boxes((48, 48), 8, 16)
    a = data_mod.generate_sample("2d", 3, truth=truth, generator_version=2)
    b = data_mod.generate_sample("2d", 3, truth=truth, generator_version=2)
    assert 200 <= a.n_views <= 400 and a.generator_version == 2
    np.testing.assert_array_equal(a.state, b.state)
    known = a.state != UNKNOWN
    np.testing.assert_array_equal(a.state[known], truth[known])


def test_sample_cache_round_trip(tmp_path, monkeypatch):
    monkeypatch.setenv("NBV_CACHE_DIR", str(tmp_path))
    calls = []

    def fake_env(dataset, seed):
        calls.append(seed)
        return random_boxes((20, 20, 20), 5, seed), 7

    monkeypatch.setattr(data_mod, "load_environment", fake_env)
    monkeypatch.setattr(data_mod, "current_generator_version", lambda: 7)
    path = data_mod.sample_path("3du", 5)
    assert path == tmp_path / "training" / "3du" / f"v{data_mod.DATA_VERSION}" / "5.npz"
    first = data_mod.load_or_generate_sample("3du", 5)
    assert path.is_file() and calls == [5]
    second = data_mod.load_or_generate_sample("3du", 5)
    assert calls == [5]  # read from the cache
    np.testing.assert_array_equal(first.state, second.state)
    assert (second.seed, second.generator_version, second.n_views) == (5, 7, first.n_views)
    monkeypatch.setattr(data_mod, "current_generator_version", lambda: 8)  # worlds changed: stale
    data_mod.load_or_generate_sample("3du", 5)
    assert calls == [5, 5]
    with pytest.raises(ValueError, match="reserved"):
        data_mod.load_samples("3du", [1000])


def test_seed_split():
    train, val, test = data_mod.TRAIN_SEEDS, data_mod.VALIDATION_SEEDS, data_mod.TEST_SEEDS
    assert (len(train), len(val), len(test)) == (100, 20, 60)
    assert len(set(train) | set(val) | set(test)) == 180 == data_mod.N_ENVIRONMENTS
    assert max(train + val + test) < data_mod.USER_SEED_START


def _tiny_2d_training(tmp_path, monkeypatch, **overrides) -> dict:
    """Fake 2D environments (random boxes on 40² maps) in a private cache; the ``train`` keyword
    arguments of a tiny run on them (``overrides`` replace single ones)."""
    monkeypatch.setenv("NBV_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(data_mod, "load_environment", lambda dataset, seed: (random_boxes((40, 40), 6, seed), 1))
    monkeypatch.setattr(data_mod, "current_generator_version", lambda: 1)
    kwargs = {
        "n_train_envs": 2,
        "n_val_envs": 1,
        "n_test_envs": 1,
        "crop": 32,
        "test_crop": 32,
        "progress": False,
        "threads": 2,
        "device": "cpu",
    }
    return {**kwargs, **overrides}


def test_train_end_to_end_and_resume(tmp_path, monkeypatch):
    kwargs = _tiny_2d_training(tmp_path, monkeypatch)
    out = tmp_path / "w" / "2d_cnn_prob.pt"
    result = train(TrainConfig("2d", 1, out, **kwargs))
    paths = side_paths(out)
    for key in ("weights", "last", "csv", "png", "card", "calibration"):
        assert paths[key].is_file(), key
    card = paths["card"].read_text()
    assert "nbv train --dataset 2d --epochs 1" in card and "0..1" in card and "100..100" in card and "120..120" in card
    model = load_model(out, dataset="2d", device="cpu")
    assert model.card["epochs"] == 1 and model.card["test_mse"] == pytest.approx(result.test_mse, abs=1e-6)
    assert model.card["validation_mse"] == pytest.approx(result.validation_mse, abs=1e-6)
    assert 0.0 <= model.card["ece"] <= 1.0 and model.card["ece"] == pytest.approx(result.ece, abs=1e-5)
    result = train(TrainConfig("2d", 2, out, **kwargs))  # resumes after epoch 1
    with open(paths["csv"]) as fh:
        rows = list(csv.DictReader(fh))
    assert [r["epoch"] for r in rows] == ["1", "2"] and result.epochs_done == 2
    with pytest.raises(ValueError, match="no-resume"):
        train(TrainConfig("2d", 3, out, **{**kwargs, "crop": 16}))

    # `out` overwritten by another run: a resumed run scores and re-writes its own best epoch
    best = torch.load(paths["last"], map_location="cpu", weights_only=True)["best_model"]
    other = tmp_path / "other" / "2d_cnn_prob.pt"
    train(TrainConfig("2d", 1, other, **{**kwargs, "seed": 5}))
    shutil.copyfile(other, out)
    again = train(TrainConfig("2d", 2, out, **kwargs))  # nothing left to train: scoring and card only
    assert again.epochs_done == 2 and again.test_mse == pytest.approx(result.test_mse, abs=1e-7)
    restored = load_model(out, dataset="2d", device="cpu")
    for key, value in restored.state_dict().items():
        assert torch.equal(value, best[key]), key
    assert train(TrainConfig("2d", 1, out, **{**kwargs, "crop": 16}, resume=False)).epochs_done == 1


def test_learning_rate_schedules():
    from nbv_prob_cnn.completion.train import learning_rate

    assert [learning_rate(1e-3, "constant", e, 4) for e in range(4)] == [1e-3] * 4
    # cosine over 4 epochs: (1 + cos(k·45°)) / 2 = 1, 0.853553, 0.5, 0.146447
    expected = [1e-3, 0.8535534e-3, 0.5e-3, 0.1464466e-3]
    assert [learning_rate(1e-3, "cosine", e, 4) for e in range(4)] == pytest.approx(expected, rel=1e-6)
    with pytest.raises(ValueError, match="schedule"):
        learning_rate(1e-3, "step", 0, 4)
    for bad in (0.0, -1e-3, float("nan")):
        with pytest.raises(ValueError, match="lr"):
            learning_rate(bad, "constant", 0, 4)


def test_train_with_a_cosine_schedule(tmp_path, monkeypatch):
    kwargs = _tiny_2d_training(tmp_path, monkeypatch, n_train_envs=1, threads=1)
    out = tmp_path / "w" / "2d_cnn_prob.pt"
    # the data set's defaults (DatasetSpec.training) apply where lr/lr_schedule are not given
    spec = dataset_spec("2d")
    training = dataclasses.replace(spec.training, lr=4e-4, lr_schedule="cosine")
    monkeypatch.setitem(DATASET_SPECS, "2d", dataclasses.replace(spec, training=training))
    train(TrainConfig("2d", 2, out, **kwargs))
    paths = side_paths(out)
    with open(paths["csv"]) as fh:
        assert [float(r["lr"]) for r in csv.DictReader(fh)] == pytest.approx([4e-4, 2e-4])
    ckpt = torch.load(paths["last"], map_location="cpu", weights_only=True)
    assert [g["lr"] for g in ckpt["optimizer"]["param_groups"]] == pytest.approx([2e-4])  # the rate Adam used last
    card = paths["card"].read_text()
    assert "Adam, lr 0.0004, cosine decay" in card and "--lr 0.0004 --lr-schedule cosine" in card
    with pytest.raises(ValueError, match="no-resume"):  # another schedule is another run
        train(TrainConfig("2d", 2, out, **{**kwargs, "lr_schedule": "constant"}))
    with pytest.raises(ValueError, match="no-resume"):  # so is another length of a cosine run
        train(TrainConfig("2d", 3, out, **kwargs))


def test_retrain_command_omits_default_out(tmp_path):
    from nbv_prob_cnn.completion.inference import default_weights_path
    from nbv_prob_cnn.completion.train_card import retrain_args

    assert retrain_args("3dt", 25, default_weights_path("3dt"), None, None, 64, 4) == (
        "nbv train --dataset 3dt --epochs 25 --crop 64"
    )
    assert retrain_args(
        "3du", 2, default_weights_path("3du", "b_city_cnn"), 3, None, None, 4, method="b_city_cnn", n_val_envs=2
    ) == ("nbv train --dataset 3du --method b_city_cnn --epochs 2 --train-envs 3 --val-envs 2")
    assert f"--out {tmp_path / 'x.pt'}" in retrain_args("3du", 2, tmp_path / "x.pt", 3, None, None, 4)
    assert retrain_args("3du", 2, default_weights_path("3du"), None, None, 16, 2, test_crop=32) == (
        "nbv train --dataset 3du --epochs 2 --crop 16 --test-crop 32 --batch-size 2"
    )
    assert "--test-crop" not in retrain_args("2d", 2, default_weights_path("2d"), None, None, 256, 8, test_crop=400)


def test_cli_arguments():
    from nbv_prob_cnn.commands import train as cmd

    parser = argparse.ArgumentParser()
    cmd.add_arguments(parser)
    args = parser.parse_args(["--dataset", "3du", "--epochs", "3", "--train-envs", "4", "--crop", "32", "--no-resume"])
    assert (args.dataset, args.epochs, args.train_envs, args.crop, args.no_resume) == ("3du", 3, 4, 32, True)
    assert cmd.NAME == "train" and callable(cmd.run)
    assert (args.lr, args.lr_schedule) == (None, None)  # the data set's (DatasetSpec.training)
    args = parser.parse_args(["--dataset", "3dt", "--lr", "3e-4", "--lr-schedule", "cosine"])
    assert (args.lr, args.lr_schedule) == (3e-4, "cosine")
    for bad in (["--dataset", "4d"], ["--dataset", "3dt", "--lr", "0"], ["--dataset", "3dt", "--lr-schedule", "step"]):
        with pytest.raises(SystemExit):
            parser.parse_args(bad)
