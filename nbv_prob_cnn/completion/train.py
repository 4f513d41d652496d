"""Training the completion CNN (SPEC §3): Adam (lr 1e-3), MSE between ``P`` and ``D``.

For weights ``out = <dir>/<stem>.pt`` training writes, next to it:

* ``<stem>.pt``: the best weights so far (lowest test loss), with their model card;
* ``<stem>.last.ckpt``: the last epoch's model, optimizer, history (resumable);
* ``<stem>.csv``: per-epoch train/test MSE and wall time; ``<stem>.png``: their plot;
* ``<stem>.md``: the model card (data set, seeds, versions, epochs, time, test MSE, command).

An epoch visits every training environment once under every augmentation rotation, in a
shuffled order (one random crop each when ``crop`` is set). The test loss is the MSE on the
test environments, unrotated, on a fixed crop per environment when ``test_crop`` is set
(2D default: 400×400, the evaluation size of SPEC §7).
"""

from __future__ import annotations

import csv
import datetime
import os
import platform
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional
from tqdm import tqdm

from nbv_prob_cnn.camera import dataset_defaults
from nbv_prob_cnn.completion.data import (
    DATA_VERSION,
    TEST_SEEDS,
    TRAIN_SEEDS,
    TrainingSample,
    crop_box,
    load_samples,
    rotations,
)
from nbv_prob_cnn.completion.inference import clear_model_cache, default_weights_path, resolve_device, save_weights
from nbv_prob_cnn.completion.model import DEFAULT_FIRST_CHANNELS, CompletionNet, count_parameters, encode_state

#: Default mini-batch size per data set (fits 2 CPU cores; see the module docs for timings).
DEFAULT_BATCH = {"2d": 8, "3du": 4, "3dt": 4}
#: Default test crop per data set (None: whole grids).
DEFAULT_TEST_CROP: dict[str, int | None] = {"2d": 400, "3du": None, "3dt": None}
LEARNING_RATE = 1e-3


@dataclass
class TrainResult:
    """What a training run produced."""

    weights: Path
    last_checkpoint: Path
    history_csv: Path
    plot: Path
    card: Path
    best_test_loss: float
    epochs_done: int


def side_paths(out: str | Path) -> dict[str, Path]:
    """Files written next to the weights file ``out``."""
    out = Path(out)
    stem = out.with_suffix("")
    return {
        "weights": out,
        "last": stem.with_name(stem.name + ".last.ckpt"),
        "csv": stem.with_suffix(".csv"),
        "png": stem.with_suffix(".png"),
        "card": stem.with_suffix(".md"),
    }


def default_threads() -> int:
    """Intra-op threads: at most 2 (the reference machine has 2 shared cores)."""
    return max(1, min(2, os.cpu_count() or 1))


def train_step(
    model: CompletionNet, optimizer: torch.optim.Optimizer, states: np.ndarray, truths: np.ndarray, device: torch.device
) -> float:
    """One Adam step on a batch ``(B, *spatial)`` of states and ground truths; returns the MSE."""
    model.train()
    x = encode_state(states).to(device)
    target = torch.as_tensor(truths, dtype=torch.float32, device=device).unsqueeze(1)
    optimizer.zero_grad(set_to_none=True)
    loss = functional.mse_loss(model(x), target)
    loss.backward()
    optimizer.step()
    return float(loss.detach())


def evaluate(
    model: CompletionNet, states: Sequence[np.ndarray], truths: Sequence[np.ndarray], device: torch.device, batch: int
) -> float:
    """Mean per-grid MSE between ``P`` and ``D`` (no gradient)."""
    model.eval()
    losses = []
    with torch.inference_mode():
        for start in range(0, len(states), batch):
            for group_s, group_t in _same_shape_groups(states[start : start + batch], truths[start : start + batch]):
                prob = model(encode_state(np.stack(group_s)).to(device))
                target = torch.as_tensor(np.stack(group_t), dtype=torch.float32, device=device).unsqueeze(1)
                per_grid = ((prob - target) ** 2).flatten(1).mean(dim=1)
                losses += per_grid.cpu().tolist()
    return float(np.mean(losses)) if losses else float("nan")


def _same_shape_groups(states: Sequence[np.ndarray], truths: Sequence[np.ndarray]):
    groups: dict[tuple[int, ...], tuple[list, list]] = {}
    for s, t in zip(states, truths, strict=True):
        g = groups.setdefault(s.shape, ([], []))
        g[0].append(s)
        g[1].append(t)
    return list(groups.values())


def _fixed_test_views(
    samples: Sequence[TrainingSample], test_crop: int | None
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    states, truths = [], []
    for sample in samples:
        box = crop_box(sample.state.shape, test_crop, np.random.default_rng([sample.seed, 404]))
        states.append(sample.state[box])
        truths.append(sample.truth[box])
    return states, truths


def retrain_args(
    dataset: str,
    epochs: int,
    out: Path,
    n_train_envs: int | None,
    n_test_envs: int | None,
    crop: int | None,
    batch_size: int,
) -> str:
    """The ``nbv train`` command line that reproduces a run."""
    cmd = f"nbv train --dataset {dataset} --epochs {epochs}"
    if Path(out).expanduser().resolve() != default_weights_path(dataset):
        cmd += f" --out {out}"
    if n_train_envs is not None:
        cmd += f" --train-envs {n_train_envs}"
    if n_test_envs is not None:
        cmd += f" --test-envs {n_test_envs}"
    if crop is not None:
        cmd += f" --crop {crop}"
    if batch_size != DEFAULT_BATCH[dataset]:
        cmd += f" --batch-size {batch_size}"
    return cmd


def _write_history(history: list[dict], csv_path: Path, png_path: Path, dataset: str) -> None:
    fields = ["epoch", "train_mse", "test_mse", "epoch_seconds", "elapsed_seconds"]
    with open(csv_path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for row in history:
            writer.writerow({k: row[k] for k in fields})
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    epochs = [r["epoch"] for r in history]
    ax.plot(epochs, [r["train_mse"] for r in history], label="train", marker=".")
    ax.plot(epochs, [r["test_mse"] for r in history], label="test", marker=".")
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE(P, D)")
    ax.set_title(f"completion CNN, {dataset}")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)


def _card_markdown(card: dict) -> str:
    lines = [f"# Completion CNN weights: {card['dataset']}", ""]
    labels = {
        "dataset": "Data set",
        "architecture": "Architecture",
        "parameters": "Parameters",
        "train_seeds": "Training environments (seeds)",
        "test_seeds": "Test environments (seeds)",
        "data_version": "Training-data simulation version",
        "generator_versions": "World generator version(s)",
        "augmentation": "Augmentation",
        "crop": "Training crop",
        "test_crop": "Test crop",
        "batch_size": "Batch size",
        "optimizer": "Optimizer",
        "epochs": "Epochs trained",
        "best_epoch": "Epoch of these weights (lowest test MSE)",
        "test_mse": "Test MSE of these weights",
        "final_test_mse": "Test MSE after the last epoch",
        "final_train_mse": "Train MSE of the last epoch",
        "wall_time_s": "Training wall time (s)",
        "device": "Device",
        "torch": "torch",
        "date": "Date",
    }
    for key, label in labels.items():
        if key in card:
            lines.append(f"* **{label}**: {card[key]}")
    if card.get("crop"):
        lines += [
            "",
            f"Trained on random {card['crop']}-cell crops of the simulated grids: the network is fully "
            "convolutional, so the weights apply to grids of any size (crops keep a training step "
            "within this machine's budget).",
        ]
    lines += ["", "Retrain with:", "", "```", card["command"], "```", ""]
    return "\n".join(lines)


def train(
    dataset: str,
    epochs: int,
    out: str | Path,
    n_train_envs: int | None = None,
    n_test_envs: int | None = None,
    crop: int | None = None,
    resume: bool = True,
    batch_size: int | None = None,
    test_crop: int | None | str = "default",
    workers: int = 1,
    threads: int | None = None,
    device: str | torch.device | None = None,
    seed: int = 0,
    progress: bool = True,
    train_seeds: Sequence[int] | None = None,
    test_seeds: Sequence[int] | None = None,
) -> TrainResult:
    """Train the completion CNN of ``dataset`` and write the weights to ``out``.

    Args:
        dataset: ``2d``, ``3du`` or ``3dt``.
        epochs: total number of epochs (a resumed run continues up to this number).
        out: weights file; the side files of :func:`side_paths` go next to it.
        n_train_envs, n_test_envs: use only the first N environments of each split.
        crop: random training crop edge (cells, per axis); None: whole grids.
        resume: continue from ``<stem>.last.ckpt`` when it exists.
        batch_size: grids per step (default :data:`DEFAULT_BATCH`).
        test_crop: fixed test crop edge; ``"default"``: :data:`DEFAULT_TEST_CROP`.
        workers: processes generating missing training data.
        threads: torch intra-op threads (default :func:`default_threads`).
        device: default CUDA when available, else CPU.
        seed: seed of initialisation, shuffling and crops.
        progress: show tqdm progress bars.
        train_seeds, test_seeds: override the environment split (default
            :data:`~nbv_prob_cnn.completion.data.TRAIN_SEEDS` / ``TEST_SEEDS``).
    """
    defaults = dataset_defaults(dataset)
    if epochs < 1:
        raise ValueError(f"epochs: expected >= 1, got {epochs}")
    out = Path(out).expanduser()
    paths = side_paths(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    batch_size = batch_size or DEFAULT_BATCH[dataset]
    test_crop = DEFAULT_TEST_CROP[dataset] if test_crop == "default" else test_crop
    train_seeds = list(TRAIN_SEEDS if train_seeds is None else train_seeds)[:n_train_envs]
    test_seeds = list(TEST_SEEDS if test_seeds is None else test_seeds)[:n_test_envs]
    if not train_seeds or not test_seeds:
        raise ValueError("train-envs/test-envs: need at least one training and one test environment")
    if set(train_seeds) & set(test_seeds):
        raise ValueError("seeds: training and test environments overlap")
    torch.set_num_threads(threads or default_threads())
    dev = resolve_device(device)
    command = retrain_args(dataset, epochs, out, n_train_envs, n_test_envs, crop, batch_size)
    run_config = {
        "dataset": dataset,
        "train_seeds": train_seeds,
        "test_seeds": test_seeds,
        "crop": crop,
        "test_crop": test_crop,
        "batch_size": batch_size,
        "seed": seed,
        "data_version": DATA_VERSION,
    }

    with tqdm(total=len(train_seeds) + len(test_seeds), desc=f"training data {dataset}", disable=not progress) as bar:
        train_samples = load_samples(dataset, train_seeds, workers, bar.update)
        test_samples = load_samples(dataset, test_seeds, workers, bar.update)
    test_states, test_truths = _fixed_test_views(test_samples, test_crop)
    rots = rotations(dataset)

    torch.manual_seed(seed)
    model = CompletionNet(defaults.dims, defaults.n_conv, DEFAULT_FIRST_CHANNELS[defaults.dims]).to(dev)
    optimizer = torch.optim.Adam(model.parameters(), lr=LEARNING_RATE)
    history: list[dict] = []
    best = {"test_mse": float("inf"), "epoch": 0}
    elapsed = 0.0
    if resume and paths["last"].is_file():
        ckpt = torch.load(paths["last"], map_location="cpu", weights_only=True)
        if ckpt.get("run_config") != run_config or ckpt.get("model_config") != model.config():
            raise ValueError(
                f"{paths['last']}: checkpoint of a different run configuration; "
                "pass --no-resume to start over or choose another --out"
            )
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        history, best, elapsed = ckpt["history"], ckpt["best"], float(ckpt["elapsed_s"])

    generator_versions = sorted({s.generator_version for s in train_samples + test_samples})
    start_epoch = len(history)
    items_per_epoch = len(train_samples) * len(rots)
    steps_per_epoch = -(-items_per_epoch // batch_size)
    bar = tqdm(
        total=steps_per_epoch * epochs,
        initial=steps_per_epoch * start_epoch,
        desc=f"train {dataset}",
        unit="step",
        disable=not progress,
    )
    for epoch in range(start_epoch, epochs):
        t0 = time.perf_counter()
        rng = np.random.default_rng([seed, epoch])
        order = rng.permutation(items_per_epoch)
        loss_sum, n_items = 0.0, 0
        for start in range(0, items_per_epoch, batch_size):
            states, truths = [], []
            for item in order[start : start + batch_size]:
                sample, rot = train_samples[item // len(rots)], rots[item % len(rots)]
                box = crop_box(sample.state.shape, crop, rng)
                states.append(rot.apply(sample.state[box]))
                truths.append(rot.apply(sample.truth[box]))
            for group_s, group_t in _same_shape_groups(states, truths):
                loss = train_step(model, optimizer, np.stack(group_s), np.stack(group_t), dev)
                loss_sum += loss * len(group_s)
                n_items += len(group_s)
            bar.update(1)
            bar.set_postfix(epoch=epoch + 1, loss=f"{loss_sum / n_items:.4f}", test=_fmt(history))
        test_mse = evaluate(model, test_states, test_truths, dev, batch_size)
        epoch_s = time.perf_counter() - t0
        elapsed += epoch_s
        history.append(
            {
                "epoch": epoch + 1,
                "train_mse": loss_sum / max(n_items, 1),
                "test_mse": test_mse,
                "epoch_seconds": round(epoch_s, 2),
                "elapsed_seconds": round(elapsed, 2),
            }
        )
        bar.set_postfix(epoch=epoch + 1, loss=f"{history[-1]['train_mse']:.4f}", test=_fmt(history))
        card = _card(dataset, model, run_config, generator_versions, rots, history, best, elapsed, dev, command)
        if test_mse < best["test_mse"]:
            best = {"test_mse": test_mse, "epoch": epoch + 1}
            card = _card(dataset, model, run_config, generator_versions, rots, history, best, elapsed, dev, command)
            save_weights(model, out, dataset, card)
            clear_model_cache()
        _update_card_file(paths, card)
        _write_history(history, paths["csv"], paths["png"], dataset)
        _save_last(paths["last"], model, optimizer, history, best, elapsed, run_config)
    bar.close()
    return TrainResult(
        out, paths["last"], paths["csv"], paths["png"], paths["card"], float(best["test_mse"]), len(history)
    )


def _fmt(history: list[dict]) -> str:
    return f"{history[-1]['test_mse']:.4f}" if history else "-"


def _card(
    dataset: str,
    model: CompletionNet,
    run_config: dict,
    generator_versions: list[int],
    rots: Sequence,
    history: list[dict],
    best: dict,
    elapsed: float,
    device: torch.device,
    command: str,
) -> dict:
    """The model card of the current best weights (plus the run so far)."""
    return {
        "dataset": dataset,
        "architecture": f"CompletionNet(dims={model.dims}, n_conv={model.n_conv}, "
        f"first_channels={model.first_channels})",
        "parameters": count_parameters(model),
        "train_seeds": _seed_ranges(run_config["train_seeds"]),
        "test_seeds": _seed_ranges(run_config["test_seeds"]),
        "data_version": DATA_VERSION,
        "generator_versions": ", ".join(map(str, generator_versions)),
        "augmentation": ", ".join(r.name for r in rots),
        "crop": run_config["crop"] or "none (whole grids)",
        "test_crop": run_config["test_crop"] or "none (whole grids)",
        "batch_size": run_config["batch_size"],
        "optimizer": f"Adam, lr {LEARNING_RATE}, MSE(P, D)",
        "epochs": len(history),
        "best_epoch": best["epoch"],
        "test_mse": round(float(best["test_mse"]), 6),
        "final_test_mse": round(float(history[-1]["test_mse"]), 6),
        "final_train_mse": round(float(history[-1]["train_mse"]), 6),
        "wall_time_s": round(elapsed, 1),
        "device": f"{device} ({platform.processor() or platform.machine()}, {torch.get_num_threads()} threads)",
        "torch": str(torch.__version__),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "command": command,
    }


def _update_card_file(paths: dict[str, Path], card: dict) -> None:
    """Write the markdown card of the best weights, with the latest run totals."""
    if not paths["weights"].is_file():
        return
    paths["card"].write_text(_card_markdown(card))


def _seed_ranges(seeds: Sequence[int]) -> str:
    seeds = sorted(seeds)
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}..{seeds[-1]} ({len(seeds)})"
    return ", ".join(map(str, seeds))


def _save_last(
    path: Path,
    model: CompletionNet,
    optimizer: torch.optim.Optimizer,
    history: list[dict],
    best: dict,
    elapsed: float,
    run_config: dict,
) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save(
        {
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "model_config": model.config(),
            "run_config": run_config,
            "history": history,
            "best": best,
            "elapsed_s": elapsed,
        },
        tmp,
    )
    os.replace(tmp, path)
