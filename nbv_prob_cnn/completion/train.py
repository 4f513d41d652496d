"""The one training loop of the project's networks (docs/method.md: completion CNN, methods): the completion CNN
(``cnn_prob``) and the City-CNN baselines (``flat_city_cnn``, ``b_city_cnn``, ``d_city_cnn``),
Adam (lr 1e-3 by default, the paper's), MSE loss (:mod:`~nbv_prob_cnn.completion.tasks` says what each one
learns). The learning rate is constant by default; ``lr_schedule="cosine"`` decays it per epoch
(:func:`learning_rate`), for runs that become unstable at a constant rate.

Environment split (:mod:`nbv_prob_cnn.basics.datasets`): training, validation, test. After every epoch
the validation loss is measured; the weights kept are those of the epoch with the lowest
validation loss (the test split never chooses anything). When training ends, the kept weights
are scored once on the test split: test MSE and, for the completion CNN, the calibration of its
probabilities on unknown cells (reliability table, ECE, reliability plot).

For weights ``out = <dir>/<stem>.pt`` training writes, next to it:

* ``<stem>.pt``: the best-validation weights so far, with their model card;
* ``<stem>.last.ckpt``: the last epoch's model, optimizer, history and the best epoch's weights (resumable);
* ``<stem>.csv``: per-epoch train/validation MSE and wall time; ``<stem>.png``: their plot;
* ``<stem>.calibration.png`` (completion CNN): reliability plot on the test split;
* ``<stem>.md``: the model card (data set, seeds, versions, epochs, time, MSEs, ECE, command).

An epoch visits every training environment once under every augmentation rotation, in a
shuffled order (one random crop each when ``crop`` is set; City-CNN crops start on the output
lattice and their targets are ray-cast through the whole rotated grid). Validation and test
items are unrotated, on a fixed crop per environment when ``test_crop`` is set.
"""

from __future__ import annotations

import copy
import csv
import datetime
import math
import os
import platform
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from tqdm import tqdm

from nbv_prob_cnn.basics.datasets import DATASET_SPECS, LR_SCHEDULES, SPEC_LEARNING_RATE, dataset_spec
from nbv_prob_cnn.completion.calibration import Reliability, reliability, save_reliability_plot
from nbv_prob_cnn.completion.city_cache import CITY_CACHE_VERSION, CachedCityExamples, CacheLayout, ensure_chunks
from nbv_prob_cnn.completion.data import DATA_VERSION, TrainingSample, crop_box, load_samples, rotations
from nbv_prob_cnn.completion.inference import clear_model_cache, default_weights_path, resolve_device, save_weights
from nbv_prob_cnn.completion.model import CompletionNet, count_parameters
from nbv_prob_cnn.completion.tasks import Example, TrainingTask

if TYPE_CHECKING:
    from nbv_prob_cnn.completion.city_scores import CityScores

#: Default mini-batch size per data set (from :mod:`nbv_prob_cnn.basics.datasets`).
DEFAULT_BATCH = {name: spec.training.batch_size for name, spec in DATASET_SPECS.items()}
#: Default validation/test crop per data set (None: whole grids).
DEFAULT_TEST_CROP: dict[str, int | None] = {name: spec.training.test_crop for name, spec in DATASET_SPECS.items()}


def learning_rate(base: float, schedule: str, epoch: int, epochs: int) -> float:
    """Learning rate of 0-based ``epoch`` of a run of ``epochs`` epochs.

    ``constant``: ``base`` throughout. ``cosine``: ``base · (1 + cos(π · epoch / epochs)) / 2``,
    from ``base`` at the first epoch down to near 0 at the last (half a cosine period, no restart).
    """
    if schedule not in LR_SCHEDULES:
        raise ValueError(f"lr schedule: expected one of {', '.join(LR_SCHEDULES)}, got {schedule!r}")
    if not (math.isfinite(base) and base > 0):
        raise ValueError(f"lr: expected a positive finite number, got {base}")
    if schedule == "constant":
        return base
    return base * 0.5 * (1.0 + math.cos(math.pi * epoch / epochs))


def _optimizer_text(lr: float, schedule: str) -> str:
    decay = ", cosine decay over the run's epochs" if schedule == "cosine" else ""
    return f"Adam, lr {lr:g}{decay}, MSE"


@dataclass
class TrainResult:
    """What a training run produced."""

    weights: Path
    last_checkpoint: Path
    history_csv: Path
    plot: Path
    card: Path
    validation_mse: float
    test_mse: float
    ece: float | None
    epochs_done: int
    validation_zero_mse: float = float("nan")
    test_zero_mse: float = float("nan")
    validation_mean_mse: float = float("nan")  # City-CNNs: MSE of predicting the mean training target
    test_mean_mse: float = float("nan")
    validation_rho: float = float("nan")  # City-CNNs: Spearman ρ, prediction vs target (city_scores)
    test_rho: float = float("nan")
    finished: bool = True  # False: a time budget ended the call before the last epoch
    validation_cell_rho: float = float("nan")  # City-CNNs: ρ of each cell's best view gain, across cells
    test_cell_rho: float = float("nan")


def side_paths(out: str | Path) -> dict[str, Path]:
    """Files written next to the weights file ``out``."""
    out = Path(out)
    stem = out.with_suffix("")
    return {
        "weights": out,
        "last": stem.with_name(stem.name + ".last.ckpt"),
        "csv": stem.with_suffix(".csv"),
        "png": stem.with_suffix(".png"),
        "calibration": stem.with_name(stem.name + ".calibration.png"),
        "card": stem.with_suffix(".md"),
    }


def default_threads() -> int:
    """Intra-op threads: at most 2 (the reference machine has 2 shared cores)."""
    return max(1, min(2, os.cpu_count() or 1))


def _batch(examples: Sequence[Example], device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    def stack(name: str) -> torch.Tensor:
        return torch.as_tensor(np.stack([getattr(e, name) for e in examples]), dtype=torch.float32, device=device)

    return stack("inputs"), stack("target"), stack("mask")


def train_step(
    model: CompletionNet | torch.nn.parallel.DistributedDataParallel,
    optimizer: torch.optim.Optimizer,
    examples: Sequence[Example],
    device: torch.device,
) -> float:
    """One Adam step on examples of equal shape; returns the MSE of ``output · mask`` and the target."""
    model.train()
    x, target, mask = _batch(examples, device)
    optimizer.zero_grad(set_to_none=True)
    loss = torch.mean((model(x) * mask - target) ** 2)
    loss.backward()
    optimizer.step()
    return float(loss.detach())


def evaluate(model: CompletionNet, examples: Sequence[Example], device: torch.device, batch: int) -> float:
    """Mean per-example MSE of ``output · mask`` and the target (no gradient)."""
    return float(np.mean(_per_example(model, examples, device, batch)[0])) if examples else float("nan")


def _per_example(
    model: CompletionNet, examples: Sequence[Example], device: torch.device, batch: int
) -> tuple[list[float], list[np.ndarray]]:
    model.eval()
    losses, outputs = [], []
    with torch.inference_mode():
        for start in range(0, len(examples), batch):
            for group in _same_shape_groups(examples[start : start + batch]):
                x, target, mask = _batch(group, device)
                out = model(x) * mask
                losses += ((out - target) ** 2).flatten(1).mean(dim=1).cpu().tolist()
                outputs += list(out.cpu().numpy())
    return losses, outputs


def _same_shape_groups(examples: Sequence[Example]) -> list[list[Example]]:
    groups: dict[tuple, list[Example]] = {}
    for e in examples:
        groups.setdefault((e.inputs.shape, e.target.shape, e.mask.shape), []).append(e)
    return list(groups.values())


def zero_output_mse(examples: Sequence[Example]) -> float:
    """Mean per-example MSE of an all-zero output (as :func:`evaluate` scores a network): the
    trivial solution that sparse targets invite, the baseline a trained network must beat."""
    return float(np.mean([np.mean(e.target.astype(np.float64) ** 2) for e in examples])) if examples else float("nan")


def mean_masked_target(examples: Sequence[Example]) -> float:
    """Mean target over the output cells the masks keep."""
    kept = [np.broadcast_to(e.mask, e.target.shape) > 0 for e in examples]
    count = sum(int(k.sum()) for k in kept)
    return sum(float(e.target[k].sum()) for e, k in zip(examples, kept, strict=True)) / count if count else float("nan")


def start_at_mean_target(model: CompletionNet, examples: Sequence[Example]) -> float:
    """Set the final bias of a sigmoid gain head to the logit of the mean masked target of
    ``examples`` (clipped to [0.001, 0.5]); returns that mean. Typical gains differ by data set
    (2D about 0.1, 3DT crops about 0.006): a head starting far above them collapsed to the
    all-zero output (3DT ``flat_city_cnn`` from logit(0.1): validation MSE equal to the all-zero
    output's to seven digits)."""
    bias = model.final.bias
    if bias is None:
        raise ValueError("model: the final conv has no bias to start at the mean target")
    mean = mean_masked_target(examples)
    p = float(np.clip(mean, 1e-3, 0.5))
    with torch.no_grad():
        bias.fill_(float(np.log(p / (1.0 - p))))
    return mean


def fixed_examples(task: TrainingTask, samples: Sequence[TrainingSample], crop: int | None) -> list[Example]:
    """Validation/test items: unrotated, one fixed crop per environment (seeded by the environment)."""
    examples = []
    for sample in samples:
        box = crop_box(sample.state.shape, crop, np.random.default_rng([sample.seed, 404]), task.align)
        examples.append(task.example(sample.state, sample.truth, box))
    return examples


def calibration_of(
    model: CompletionNet, task: TrainingTask, samples: Sequence[TrainingSample], crop: int | None, device, batch: int
) -> Reliability:
    """Reliability of the completion CNN's probabilities on the unknown cells of ``samples``."""
    examples = fixed_examples(task, samples, crop)
    _, outputs = _per_example(model, examples, device, batch)
    predicted, occupied = [], []
    for example, out in zip(examples, outputs, strict=True):
        unknown = (example.inputs[0] == 0) & (example.inputs[1] == 0)
        predicted.append(np.clip(out[0][unknown], 0.0, 1.0))
        occupied.append(example.target[0][unknown])
    return reliability(np.concatenate(predicted), np.concatenate(occupied))


def retrain_args(
    dataset: str,
    epochs: int,
    out: Path,
    n_train_envs: int | None,
    n_test_envs: int | None,
    crop: int | None,
    batch_size: int,
    *,
    method: str = "cnn_prob",
    n_val_envs: int | None = None,
    test_crop: int | None = None,
    lr: float = SPEC_LEARNING_RATE,
    lr_schedule: str = "constant",
    patience: int | None = None,
) -> str:
    """The ``nbv train`` command line that reproduces a run."""
    cmd = f"nbv train --dataset {dataset}"
    if method != "cnn_prob":
        cmd += f" --method {method}"
    cmd += f" --epochs {epochs}"
    if Path(out).expanduser().resolve() != default_weights_path(dataset, method):
        cmd += f" --out {out}"
    for flag, value in (("--train-envs", n_train_envs), ("--val-envs", n_val_envs), ("--test-envs", n_test_envs)):
        if value is not None:
            cmd += f" {flag} {value}"
    if crop is not None:
        cmd += f" --crop {crop}"
    if test_crop is not None and test_crop != DEFAULT_TEST_CROP[dataset]:
        cmd += f" --test-crop {test_crop}"
    if batch_size != DEFAULT_BATCH[dataset]:
        cmd += f" --batch-size {batch_size}"
    if lr != SPEC_LEARNING_RATE:
        cmd += f" --lr {lr:g}"
    if lr_schedule != "constant":
        cmd += f" --lr-schedule {lr_schedule}"
    if patience is not None:
        cmd += f" --patience {patience}"
    return cmd


def _write_history(history: list[dict], csv_path: Path, png_path: Path, title: str) -> None:
    fields = ["epoch", "train_mse", "validation_mse", "epoch_seconds", "elapsed_seconds", "lr"]
    if any("validation_rho" in row for row in history):  # City-CNNs
        fields.insert(3, "validation_rho")
    if any("validation_cell_rho" in row for row in history):  # City-CNN runs since cell ρ was scored
        fields.insert(4, "validation_cell_rho")
    with open(csv_path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for row in history:  # "lr" is missing from histories of checkpoints written before it was logged
            writer.writerow({k: row.get(k, "") for k in fields})
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4))
    ax = fig.add_subplot(1, 1, 1)
    epochs = [r["epoch"] for r in history]
    ax.plot(epochs, [r["train_mse"] for r in history], label="train", marker=".")
    ax.plot(epochs, [r["validation_mse"] for r in history], label="validation", marker=".")
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)


def _card_markdown(card: dict) -> str:
    lines = [f"# {card.get('model', 'cnn_prob')} weights: {card['dataset']}", ""]
    labels = {
        "dataset": "Data set",
        "model": "Model (method)",
        "architecture": "Architecture",
        "parameters": "Parameters",
        "train_seeds": "Training environments (seeds)",
        "validation_seeds": "Validation environments (seeds)",
        "test_seeds": "Test environments (seeds)",
        "data_version": "Training-data simulation version",
        "generator_versions": "World generator version(s)",
        "augmentation": "Augmentation",
        "crop": "Training crop",
        "test_crop": "Validation/test crop",
        "batch_size": "Batch size",
        "optimizer": "Optimizer",
        "epochs": "Epochs trained",
        "best_epoch": "Epoch of these weights (lowest validation MSE)",
        "validation_mse": "Validation MSE of these weights",
        "validation_zero_mse": "Validation MSE of an all-zero output (baseline)",
        "test_mse": "Test MSE of these weights",
        "test_zero_mse": "Test MSE of an all-zero output (baseline)",
        "validation_mean_mse": "Validation MSE of predicting the mean training target (baseline)",
        "test_mean_mse": "Test MSE of predicting the mean training target (baseline)",
        "validation_rho": "Spearman ρ, prediction vs target, validation grids (mean over grids)",
        "test_rho": "Spearman ρ, prediction vs target, test grids (mean over grids)",
        "validation_cell_rho": "Cell ρ (each cell's best view gain, across cells), validation grids",
        "test_cell_rho": "Cell ρ (each cell's best view gain, across cells), test grids",
        "examples": "Training examples",
        "patience": "Early stopping",
        "stopped": "Stopped",
        "ece": "Calibration on the test split, unknown cells (ECE, 10 bins)",
        "final_validation_mse": "Validation MSE after the last epoch",
        "final_train_mse": "Train MSE of the last epoch",
        "wall_time_s": "Training wall time (s)",
        "device": "Device",
        "torch": "torch",
        "date": "Date",
    }
    for key, label in labels.items():
        if key in card:
            lines.append(f"* **{label}**: {card[key]}")
    if card.get("note"):
        lines += ["", card["note"]]
    if card.get("crop") and card["crop"] != "none (whole grids)":
        lines += [
            "",
            (
                f"Trained on random {card['crop']}-cell crops of the simulated grids: the network is fully "
                "convolutional, so the weights apply to grids of any size (crops keep a training step "
                "within this machine's budget)."
            ),
        ]
    lines += ["", "Retrain with:", "", "```", card["command"], "```", ""]
    return "\n".join(lines)


def train(
    dataset: str,
    epochs: int,
    out: str | Path | None = None,
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
    method: str = "cnn_prob",
    n_val_envs: int | None = None,
    validation_seeds: Sequence[int] | None = None,
    first_channels: int | None = None,
    backend: str = "auto",
    note: str = "",
    lr: float | None = None,
    lr_schedule: str | None = None,
    cache: bool = True,
    patience: int | None = None,
    time_budget_s: float | None = None,
    warm_start: str | Path | None = None,
) -> TrainResult:
    """Train the network ``method`` of ``dataset`` and write the weights to ``out``.

    Args:
        dataset: ``2d``, ``3du`` or ``3dt``.
        epochs: total number of epochs (a resumed run continues up to this number).
        out: weights file (default ``nbv_prob_cnn/weights/<dataset>_<method>.pt``); the side
            files of :func:`side_paths` go next to it.
        n_train_envs, n_val_envs, n_test_envs: use only the first N environments of each split.
        crop: random training crop edge (cells, per axis); None: whole grids.
        resume: continue from ``<stem>.last.ckpt`` when it exists.
        batch_size: grids per step (default :data:`DEFAULT_BATCH`).
        test_crop: fixed validation/test crop edge; ``"default"``: :data:`DEFAULT_TEST_CROP`.
        workers: processes generating missing training data.
        threads: torch intra-op threads (default :func:`default_threads`).
        device: default CUDA when available, else CPU.
        seed: seed of initialisation, shuffling and crops.
        progress: show tqdm progress bars.
        train_seeds, validation_seeds, test_seeds: override the environment split (default:
            the data set's, :mod:`nbv_prob_cnn.basics.datasets`).
        method: ``cnn_prob`` (completion CNN) or a City-CNN variant.
        first_channels: width of the first conv block (default 8 in 2D, 16 in 3D).
        backend: ray-casting backend of the City-CNN targets.
        note: a sentence for the model card (e.g. why a run was short).
        lr: Adam's (initial) learning rate (default: the data set's, :mod:`nbv_prob_cnn.basics.datasets`;
            the paper's 1e-3 except on 3DT).
        lr_schedule: ``constant`` or ``cosine`` (:func:`learning_rate`; default: the data set's).
        cache: City-CNNs read their examples from the cached training set
            (:mod:`~nbv_prob_cnn.completion.city_cache`, generated first where missing) instead of
            ray-casting targets in every step. Ignored for ``cnn_prob``.
        patience: stop early once the validation MSE has not improved for this many epochs
            (None: run all ``epochs``).
        time_budget_s: end this call after the first epoch that ends past this many seconds
            (checkpoint written; no test scoring; ``finished`` is False): to share a CPU between
            several runs that each resume later.
        warm_start: a weights file of the same architecture (e.g. the shipped weights of an
            earlier run of this command, with its loss-curve CSV beside it) to start from when
            there is no checkpoint to resume: the weights, and the history up to their epoch, are
            taken over; the optimizer state starts anew (:func:`warm_start_state`).
    """
    # imported here: `python -m nbv_prob_cnn.completion.city_scores` runs that module as a script
    from nbv_prob_cnn.completion.city_scores import mean_target_per_channel, score_city

    spec = dataset_spec(dataset)
    task = TrainingTask(method, spec, backend)
    if epochs < 1:
        raise ValueError(f"epochs: expected >= 1, got {epochs}")
    if patience is not None and patience < 1:
        raise ValueError(f"patience: expected >= 1 epochs, got {patience}")
    lr = spec.training.lr if lr is None else lr
    lr_schedule = spec.training.lr_schedule if lr_schedule is None else lr_schedule
    learning_rate(lr, lr_schedule, 0, epochs)  # validates both
    out = Path(out).expanduser() if out is not None else default_weights_path(dataset, method)
    paths = side_paths(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    batch_size = batch_size or DEFAULT_BATCH[dataset]
    explicit_crop = None if test_crop is None else int(test_crop) if test_crop != "default" else None
    crop_edge = DEFAULT_TEST_CROP[dataset] if test_crop == "default" else explicit_crop
    train_seeds = list(spec.train_seeds if train_seeds is None else train_seeds)[:n_train_envs]
    val_seeds = list(spec.validation_seeds if validation_seeds is None else validation_seeds)[:n_val_envs]
    test_seeds = list(spec.test_seeds if test_seeds is None else test_seeds)[:n_test_envs]
    if not train_seeds or not val_seeds or not test_seeds:
        raise ValueError("train/val/test envs: need at least one training, validation and test environment")
    if set(train_seeds) & set(test_seeds) or set(train_seeds) & set(val_seeds) or set(val_seeds) & set(test_seeds):
        raise ValueError("seeds: training, validation and test environments overlap")
    torch.set_num_threads(threads or default_threads())
    dev = resolve_device(device)
    command = retrain_args(
        dataset, epochs, out, n_train_envs, n_test_envs, crop, batch_size, method=method, n_val_envs=n_val_envs,
        test_crop=crop_edge, lr=lr, lr_schedule=lr_schedule, patience=patience,
    )  # fmt: skip
    run_config = {
        "dataset": dataset,
        "method": method,
        "train_seeds": train_seeds,
        "validation_seeds": val_seeds,
        "test_seeds": test_seeds,
        "crop": crop,
        "test_crop": crop_edge,
        "batch_size": batch_size,
        "seed": seed,
        "data_version": DATA_VERSION,
    }
    cached = cache and not task.is_completion
    rank, world = _rank_and_world()
    if world > 1 and time_budget_s is not None:
        raise ValueError("time_budget_s: not available in data-parallel training (the workers must stop together)")
    progress = progress and rank == 0
    if cached:  # absent otherwise: older checkpoints still resume
        run_config["examples"] = f"cached v{CITY_CACHE_VERSION}"
    if lr != SPEC_LEARNING_RATE or lr_schedule != "constant":  # absent by default: older checkpoints still resume
        run_config["optimizer"] = _optimizer_text(lr, lr_schedule)
        if lr_schedule == "cosine":  # the schedule depends on the run's length
            run_config["epochs"] = epochs

    rots = rotations(dataset)
    if cached:
        layout = CacheLayout.for_training(dataset, crop, crop_edge)
        chunk_seeds = {"train": train_seeds, "eval": val_seeds + test_seeds}
        if world > 1:  # each worker generates its share, then every one checks it sees them all
            ensure_chunks(layout, chunk_seeds, backend, progress and rank == 0, share=(rank, world))
            torch.distributed.barrier()
        ensure_chunks(layout, chunk_seeds, backend, progress and rank == 0)
        source: _CachedSource | _SampleSource = _CachedSource(
            CachedCityExamples(method, layout, train_seeds, val_seeds, test_seeds, crop)
        )
    else:
        n_envs = len(train_seeds) + len(val_seeds) + len(test_seeds)
        with tqdm(total=n_envs, desc=f"training data {dataset}", disable=not progress) as bar:
            train_samples = load_samples(dataset, train_seeds, workers, bar.update)
            val_samples = load_samples(dataset, val_seeds, workers, bar.update)
            test_samples = load_samples(dataset, test_seeds, workers, bar.update)
        source = _SampleSource(task, train_samples, val_samples, test_samples, crop, crop_edge)
    val_examples = source.validation()
    mean_target = (
        np.zeros(1, np.float32) if task.is_completion else mean_target_per_channel(source.mean_target_examples())
    )
    zero: dict[str, float] = {"validation_zero_mse": zero_output_mse(val_examples)} if task.is_completion else {}

    torch.manual_seed(seed)
    model = task.build(first_channels).to(dev)
    if model.head == "sigmoid" and model.final.bias is not None:  # City-CNN gain heads (a resume overwrites it)
        start_at_mean_target(model, source.first_examples(8, np.random.default_rng([seed, 0x1B1A5])))
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    history: list[dict] = []
    best: dict[str, Any] = {"validation_mse": float("inf"), "epoch": 0}
    best_state: dict[str, torch.Tensor] | None = None  # the kept epoch's weights (also in the checkpoint)
    elapsed = 0.0
    warm = False  # started from warm_start's weights (no checkpoint to resume)
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
        best_state = ckpt.get("best_model")  # None in checkpoints written before it was stored
    elif warm_start is not None:
        warm = True
        history, best, elapsed = warm_start_state(Path(warm_start), model)
        best_state = {k: v.detach().to("cpu", copy=True) for k, v in model.state_dict().items()}
        note = (note + " " if note else "") + (
            f"Warm start at epoch {best['epoch']} from {Path(warm_start).name} (its weights and history; "
            "the optimizer state started anew)."
        )

    net = model if world == 1 else torch.nn.parallel.DistributedDataParallel(model)
    generator_versions = source.generator_versions()
    card_config = {**run_config, **({"patience": patience} if patience is not None else {})}
    card_args = (dataset, method, model, card_config, generator_versions, rots, dev, command, note, zero)
    if warm and rank == 0:  # the output holds the starting weights until an epoch beats them
        save_weights(model, out, dataset, _card(*card_args, history, best, elapsed), name=method)
    start_epoch = len(history)
    call_start = time.perf_counter()
    items_per_epoch = len(train_seeds) * len(rots)
    steps_per_epoch = -(-items_per_epoch // batch_size)
    bar = tqdm(
        total=steps_per_epoch * epochs,
        initial=steps_per_epoch * min(start_epoch, epochs),
        desc=f"train {dataset} {method}",
        unit="step",
        disable=not progress,
    )
    for epoch in range(start_epoch, epochs):
        if _stopped_early(history, best, patience):
            break
        t0 = time.perf_counter()
        epoch_lr = learning_rate(lr, lr_schedule, epoch, epochs)
        for group_params in optimizer.param_groups:
            group_params["lr"] = epoch_lr
        rng = np.random.default_rng([seed, epoch])
        order = rng.permutation(items_per_epoch)
        loss_sum, n_items = 0.0, 0
        for start in range(0, items_per_epoch, batch_size):
            items = [int(item) for item in order[start : start + batch_size]]
            # data-parallel: worker r builds items r, r + world, ...; every worker draws every
            # item's random crop so that all follow the single-process random sequence
            mine = [k % world == rank for k in range(len(items))] if len(items) >= world else [False] * len(items)
            examples = []
            for item, own in zip(items, mine, strict=True):
                example = source.train_example(item // len(rots), item % len(rots), rng, build=own)
                if example is not None:
                    examples.append(example)
            groups = _same_shape_groups(examples)
            if world > 1 and len(groups) > 1:
                raise ValueError("data-parallel training needs equal-shape examples in a step: set a crop")
            for group in groups:
                loss = train_step(net, optimizer, group, dev)
                loss_sum += loss * len(group)
                n_items += len(group)
            bar.update(1)
            bar.set_postfix(epoch=epoch + 1, loss=f"{loss_sum / max(n_items, 1):.4f}", val=_fmt(history))
        if world > 1:
            loss_sum, n_items = _sum_over_workers(loss_sum, n_items)
        val_scores = None
        if task.is_completion:
            val_mse = evaluate(model, val_examples, dev, batch_size)
            if world > 1:
                val_mse = _from_rank0(val_mse)
        else:
            val_scores = score_city(model, method, spec, val_examples, mean_target, dev, batch_size)
            val_mse = val_scores.mse
            if world > 1:  # rank 0's score decides for all (early stopping must agree)
                val_mse = _from_rank0(val_mse)
            zero.update(_baselines("validation", val_scores))  # in place: card_args holds this dict
        epoch_s = time.perf_counter() - t0
        elapsed += epoch_s
        history.append(
            {
                "epoch": epoch + 1,
                "train_mse": loss_sum / max(n_items, 1),
                "validation_mse": val_mse,
                "epoch_seconds": round(epoch_s, 2),
                "elapsed_seconds": round(elapsed, 2),
                "lr": epoch_lr,
                **(
                    {"validation_rho": round(val_scores.rho, 5), "validation_cell_rho": round(val_scores.cell_rho, 5)}
                    if val_scores is not None
                    else {}
                ),
            }
        )
        bar.set_postfix(epoch=epoch + 1, loss=f"{history[-1]['train_mse']:.4f}", val=_fmt(history))
        if val_mse < best["validation_mse"]:
            best = {"validation_mse": val_mse, "epoch": epoch + 1}
            if val_scores is not None:
                best["validation_rho"] = val_scores.rho
                best["validation_cell_rho"] = val_scores.cell_rho
            best_state = {k: v.detach().to("cpu", copy=True) for k, v in model.state_dict().items()}
            if rank == 0:
                save_weights(model, out, dataset, _card(*card_args, history, best, elapsed), name=method)
                clear_model_cache()
        if rank == 0:
            _write_history(history, paths["csv"], paths["png"], f"{method}, {dataset}")
            _save_last(paths["last"], model, optimizer, history, best, elapsed, run_config, best_state)
            _update_card_file(paths, _card(*card_args, history, best, elapsed))
        out_of_time = time_budget_s is not None and time.perf_counter() - call_start > time_budget_s
        if out_of_time and epoch + 1 < epochs and not _stopped_early(history, best, patience):
            bar.close()
            return TrainResult(
                    out, paths["last"], paths["csv"], paths["png"], paths["card"], float(best["validation_mse"]),
                    float("nan"), None, len(history), finished=False,
                    validation_rho=float(best.get("validation_rho", float("nan"))),
                    validation_cell_rho=float(best.get("validation_cell_rho", float("nan"))),
                )  # fmt: skip
    bar.close()
    if rank != 0:  # rank 0 scores the kept weights and writes the card
        return TrainResult(
            out, paths["last"], paths["csv"], paths["png"], paths["card"], float(best["validation_mse"]),
            float("nan"), None, len(history),
        )  # fmt: skip

    # The kept (best-validation) weights, scored once on the test split: taken from the run's
    # own state, not from `out`, which a resumed run may have found overwritten by another run.
    if best_state is not None:
        kept = copy.deepcopy(model)
        kept.load_state_dict(best_state)
        kept.eval()
    else:  # a checkpoint without its best weights: `out` is assumed to hold them
        from nbv_prob_cnn.completion.inference import load_model

        kept = load_model(out, dataset, dev, model_name=method)
    test_examples = source.test()
    if task.is_completion:
        test_mse = evaluate(kept, test_examples, dev, batch_size)
        zero["test_zero_mse"] = zero_output_mse(test_examples)
    else:
        kept_val = score_city(kept, method, spec, val_examples, mean_target, dev, batch_size)
        test_scores = score_city(kept, method, spec, test_examples, mean_target, dev, batch_size)
        test_mse = test_scores.mse
        zero.update({**_baselines("validation", kept_val), **_baselines("test", test_scores)})
        best = {
            **best,
            "validation_rho": kept_val.rho,
            "test_rho": test_scores.rho,
            "validation_cell_rho": kept_val.cell_rho,
            "test_cell_rho": test_scores.cell_rho,
        }
    best = {**best, "test_mse": test_mse}
    if _stopped_early(history, best, patience) and len(history) < epochs:
        best["stopped"] = f"early at epoch {len(history)} of {epochs}: no lower validation MSE for {patience} epochs"
    if task.is_completion:
        assert isinstance(source, _SampleSource)
        table = calibration_of(kept, task, source.test_samples, crop_edge, dev, batch_size)
        save_reliability_plot(table, paths["calibration"], f"{dataset}: calibration on the test split")
        best["ece"] = table.ece
    card = _card(*card_args, history, best, elapsed)
    save_weights(kept, out, dataset, card, name=method)
    clear_model_cache()
    _update_card_file(paths, card)
    return TrainResult(
        out,
        paths["last"],
        paths["csv"],
        paths["png"],
        paths["card"],
        float(best["validation_mse"]),
        float(test_mse),
        best.get("ece"),
        len(history),
        zero["validation_zero_mse"],
        zero["test_zero_mse"],
        zero.get("validation_mean_mse", float("nan")),
        zero.get("test_mean_mse", float("nan")),
        float(best.get("validation_rho", float("nan"))),
        float(best.get("test_rho", float("nan"))),
        validation_cell_rho=float(best.get("validation_cell_rho", float("nan"))),
        test_cell_rho=float(best.get("test_cell_rho", float("nan"))),
    )


def _rank_and_world() -> tuple[int, int]:
    """``(rank, world size)`` of the torch.distributed group (``(0, 1)`` outside one)."""
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


def _sum_over_workers(loss_sum: float, n_items: int) -> tuple[float, int]:
    totals = torch.tensor([loss_sum, float(n_items)], dtype=torch.float64)
    torch.distributed.all_reduce(totals)
    return float(totals[0]), int(totals[1])


def _from_rank0(value: float) -> float:
    tensor = torch.tensor([value], dtype=torch.float64)
    torch.distributed.broadcast(tensor, src=0)
    return float(tensor[0])


class _SampleSource:
    """Examples computed from the simulated samples on the fly (``cnn_prob``; City-CNNs with
    ``cache=False``: their targets are ray-cast in every step)."""

    def __init__(
        self,
        task: TrainingTask,
        train_samples: list[TrainingSample],
        val_samples: list[TrainingSample],
        test_samples: list[TrainingSample],
        crop: int | None,
        crop_edge: int | None,
    ) -> None:
        self.task, self.crop, self.crop_edge = task, crop, crop_edge
        self.train_samples, self.val_samples, self.test_samples = train_samples, val_samples, test_samples
        self.rots = rotations(task.spec.name)

    def train_example(self, index: int, rotation: int, rng: np.random.Generator, build: bool = True) -> Example | None:
        """The item's example (its random crop drawn from ``rng``); None, with the same draw,
        when ``build`` is False."""
        sample, rot = self.train_samples[index], self.rots[rotation]
        box = crop_box(rot.rotated_shape(sample.state.shape), self.crop, rng, self.task.align)
        if not build:
            return None
        return self.task.example(rot.apply(sample.state), rot.apply(sample.truth), box)

    def first_examples(self, n: int, rng: np.random.Generator) -> list[Example]:
        first = self.train_samples[:n]
        boxes = [crop_box(s.state.shape, self.crop, rng, self.task.align) for s in first]
        return [self.task.example(s.state, s.truth, b) for s, b in zip(first, boxes, strict=True)]

    def mean_target_examples(self) -> list[Example]:
        """The mean-target baseline's examples: the fixed crops of the first 8 training grids."""
        return fixed_examples(self.task, self.train_samples[:8], self.crop)

    def validation(self) -> list[Example]:
        return fixed_examples(self.task, self.val_samples, self.crop_edge)

    def test(self) -> list[Example]:
        return fixed_examples(self.task, self.test_samples, self.crop_edge)

    def generator_versions(self) -> list[int]:
        return sorted({s.generator_version for s in self.train_samples + self.val_samples + self.test_samples})


class _CachedSource:
    """City-CNN examples read from the cached training set (no ray casting)."""

    def __init__(self, examples: CachedCityExamples) -> None:
        self.examples = examples

    def train_example(self, index: int, rotation: int, rng: np.random.Generator, build: bool = True) -> Example | None:
        return self.examples.train_example(index, rotation, rng, build)

    def first_examples(self, n: int, rng: np.random.Generator) -> list[Example]:
        return self.examples.first_examples(n, rng)

    def mean_target_examples(self) -> Sequence[Example]:
        """The mean-target baseline's examples: the unrotated stored example of every training grid."""
        return self.examples.unrotated_training()

    def validation(self) -> Sequence[Example]:
        return self.examples.fixed(self.examples.validation_seeds)

    def test(self) -> Sequence[Example]:
        return self.examples.fixed(self.examples.test_seeds)

    def generator_versions(self) -> list[int]:
        return self.examples.generator_versions()


def _stopped_early(history: list[dict], best: dict, patience: int | None) -> bool:
    """True once ``patience`` epochs have passed since the best validation epoch."""
    return patience is not None and bool(history) and len(history) - int(best["epoch"]) >= patience


def _baselines(split: str, scores: CityScores) -> dict[str, float]:
    return {f"{split}_zero_mse": scores.zero_mse, f"{split}_mean_mse": scores.mean_mse}


def _fmt(history: list[dict]) -> str:
    return f"{history[-1]['validation_mse']:.4f}" if history else "-"


def _card(
    dataset: str,
    method: str,
    model: CompletionNet,
    run_config: dict,
    generator_versions: list[int],
    rots: Sequence,
    device: torch.device,
    command: str,
    note: str,
    zero: dict[str, float],
    history: list[dict],
    best: dict,
    elapsed: float,
) -> dict:
    """The model card of the current best weights (plus the run so far)."""
    arch = ", ".join(f"{k}={v}" for k, v in model.config().items())
    card = {
        "dataset": dataset,
        "model": method,
        "architecture": f"CompletionNet({arch})",
        "parameters": count_parameters(model),
        "train_seeds": _seed_ranges(run_config["train_seeds"]),
        "validation_seeds": _seed_ranges(run_config["validation_seeds"]),
        "test_seeds": _seed_ranges(run_config["test_seeds"]),
        "data_version": DATA_VERSION,
        "generator_versions": ", ".join(map(str, generator_versions)),
        "augmentation": ", ".join(r.name for r in rots),
        "crop": run_config["crop"] or "none (whole grids)",
        "test_crop": run_config["test_crop"] or "none (whole grids)",
        "batch_size": run_config["batch_size"],
        "optimizer": run_config.get("optimizer", _optimizer_text(SPEC_LEARNING_RATE, "constant")),
        "epochs": len(history),
        "best_epoch": best["epoch"],
        "validation_mse": round(float(best["validation_mse"]), 6),
        "final_validation_mse": round(float(history[-1]["validation_mse"]), 6),
        "final_train_mse": round(float(history[-1]["train_mse"]), 6),
        "wall_time_s": round(elapsed, 1),
        "device": f"{device} ({platform.processor() or platform.machine()}, {torch.get_num_threads()} threads)",
        "torch": str(torch.__version__),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "command": command,
    }
    if "test_mse" in best:
        card["test_mse"] = round(float(best["test_mse"]), 6)
    for key, value in zero.items():
        card[key] = round(float(value), 6)
    if "ece" in best:
        card["ece"] = round(float(best["ece"]), 5)
    for key in ("validation_rho", "test_rho", "validation_cell_rho", "test_cell_rho"):
        if key in best:
            card[key] = round(float(best[key]), 4)
    if "stopped" in best:
        card["stopped"] = best["stopped"]
    if "patience" in run_config:
        card["patience"] = f"{run_config['patience']} epochs without a lower validation MSE"
    if "examples" in run_config:
        card["examples"] = run_config["examples"] + " City-CNN training set (city_cache: no ray casting in a step)"
    if note:
        card["note"] = note
    return card


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


def warm_start_state(path: Path, model: CompletionNet) -> tuple[list[dict], dict, float]:
    """Load the weights file ``path`` into ``model``; return the history of its run up to the
    epoch of those weights (``<stem>.csv`` beside it), the best entry and the elapsed seconds.

    Raises:
        ValueError: missing or unreadable file or CSV, another architecture, or a file without
            the epoch of its weights (not written by :func:`train`).
    """
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, EOFError) as exc:
        raise ValueError(f"warm start: cannot read {path}: {exc}") from exc
    config = {k: v for k, v in payload.get("config", {}).items() if k not in ("dataset", "model")}
    if config != model.config():
        raise ValueError(f"warm start: {path} holds {config}, not this run's architecture {model.config()}")
    card = payload.get("card", {})
    epoch = int(card.get("best_epoch", 0))
    csv_path = path.with_suffix(".csv")
    if epoch < 1 or not csv_path.is_file():
        raise ValueError(f"warm start: {path} needs the epoch of its weights and its loss curve {csv_path}")
    with open(csv_path, newline="") as fh:
        rows = [
            {k: (int(v) if k == "epoch" else float(v)) for k, v in row.items() if v != ""} for row in csv.DictReader(fh)
        ]
    history = [row for row in rows if row["epoch"] <= epoch]
    if len(history) != epoch:
        raise ValueError(f"warm start: {csv_path} lacks epochs 1..{epoch}")
    model.load_state_dict(payload["state_dict"])
    best: dict[str, Any] = {"validation_mse": float(history[-1]["validation_mse"]), "epoch": epoch}
    for key in ("validation_rho", "validation_cell_rho"):
        if key in history[-1]:
            best[key] = float(history[-1][key])
    return history, best, float(history[-1].get("elapsed_seconds", 0.0))


def _save_last(
    path: Path,
    model: CompletionNet,
    optimizer: torch.optim.Optimizer,
    history: list[dict],
    best: dict,
    elapsed: float,
    run_config: dict,
    best_state: dict[str, torch.Tensor] | None,
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
            "best_model": best_state,
        },
        tmp,
    )
    os.replace(tmp, path)
