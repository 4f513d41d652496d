"""The model card of a training run (:func:`~nbv_prob_cnn.completion.train.train`): the facts of the run
(data set, seeds, versions, crops, optimizer, command), its scores so far, and the markdown ``<stem>.md``
written beside the weights."""

from __future__ import annotations

import datetime
import platform
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from nbv_prob_cnn.basics.datasets import DATASET_SPECS, SPEC_LEARNING_RATE
from nbv_prob_cnn.completion.data import DATA_VERSION
from nbv_prob_cnn.completion.inference import default_weights_path
from nbv_prob_cnn.completion.model import CompletionNet, count_parameters

#: Card keys and their labels in the markdown, in order.
CARD_LABELS = {
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


def optimizer_text(lr: float, schedule: str) -> str:
    """The card's optimizer line."""
    decay = ", cosine decay over the run's epochs" if schedule == "cosine" else ""
    return f"Adam, lr {lr:g}{decay}, MSE"


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
    training = DATASET_SPECS[dataset].training
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
    if test_crop is not None and test_crop != training.test_crop:
        cmd += f" --test-crop {test_crop}"
    if batch_size != training.batch_size:
        cmd += f" --batch-size {batch_size}"
    if lr != SPEC_LEARNING_RATE:
        cmd += f" --lr {lr:g}"
    if lr_schedule != "constant":
        cmd += f" --lr-schedule {lr_schedule}"
    if patience is not None:
        cmd += f" --patience {patience}"
    return cmd


@dataclass
class CardFacts:
    """What a run's card says besides its scores.

    Attributes:
        run_config: the run's settings (seeds, crops, batch size; ``optimizer``, ``patience`` and
            ``examples`` where they differ from the defaults).
        zero: the baselines' MSEs by card key (updated in place as the validation scores come in).
    """

    dataset: str
    method: str
    model: CompletionNet
    run_config: dict
    generator_versions: list[int]
    rotation_names: Sequence[str]
    device: torch.device
    command: str
    note: str
    zero: dict[str, float]


def model_card(facts: CardFacts, history: list[dict], best: dict, elapsed: float) -> dict:
    """The model card of the current best weights (plus the run so far)."""
    arch = ", ".join(f"{k}={v}" for k, v in facts.model.config().items())
    run_config = facts.run_config
    card = {
        "dataset": facts.dataset,
        "model": facts.method,
        "architecture": f"CompletionNet({arch})",
        "parameters": count_parameters(facts.model),
        "train_seeds": seed_ranges(run_config["train_seeds"]),
        "validation_seeds": seed_ranges(run_config["validation_seeds"]),
        "test_seeds": seed_ranges(run_config["test_seeds"]),
        "data_version": DATA_VERSION,
        "generator_versions": ", ".join(map(str, facts.generator_versions)),
        "augmentation": ", ".join(facts.rotation_names),
        "crop": run_config["crop"] or "none (whole grids)",
        "test_crop": run_config["test_crop"] or "none (whole grids)",
        "batch_size": run_config["batch_size"],
        "optimizer": run_config.get("optimizer", optimizer_text(SPEC_LEARNING_RATE, "constant")),
        "epochs": len(history),
        "best_epoch": best["epoch"],
        "validation_mse": round(float(best["validation_mse"]), 6),
        "final_validation_mse": round(float(history[-1]["validation_mse"]), 6),
        "final_train_mse": round(float(history[-1]["train_mse"]), 6),
        "wall_time_s": round(elapsed, 1),
        "device": f"{facts.device} ({platform.processor() or platform.machine()}, {torch.get_num_threads()} threads)",
        "torch": str(torch.__version__),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "command": facts.command,
    }
    if "test_mse" in best:
        card["test_mse"] = round(float(best["test_mse"]), 6)
    for key, value in facts.zero.items():
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
    if facts.note:
        card["note"] = facts.note
    return card


def card_markdown(card: dict) -> str:
    """The card as markdown: one labelled line per key, the note, the crop's remark and the command."""
    lines = [f"# {card.get('model', 'cnn_prob')} weights: {card['dataset']}", ""]
    for key, label in CARD_LABELS.items():
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


def write_card_file(paths: dict[str, Path], card: dict) -> None:
    """Write the markdown card of the best weights, with the latest run totals (once the weights exist)."""
    if not paths["weights"].is_file():
        return
    paths["card"].write_text(card_markdown(card))


def seed_ranges(seeds: Sequence[int]) -> str:
    """``first..last (count)`` for consecutive seeds, else the list."""
    seeds = sorted(seeds)
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}..{seeds[-1]} ({len(seeds)})"
    return ", ".join(map(str, seeds))
