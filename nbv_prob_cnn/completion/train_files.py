"""What a training run (:func:`~nbv_prob_cnn.completion.train.train`) writes beside its weights file and
reads back: the paths, the loss history (CSV and plot), the resumable checkpoint, and the weights and history
of an earlier run to start from."""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from nbv_prob_cnn.completion.model import CompletionNet


@dataclass
class RunState:
    """Where a run stands: its network and optimizer, the per-epoch history, the best epoch so far
    (``best``: its validation MSE, epoch and scores) with its weights, and the training seconds so far."""

    model: CompletionNet
    optimizer: torch.optim.Optimizer
    history: list[dict] = field(default_factory=list)
    best: dict[str, Any] = field(default_factory=lambda: {"validation_mse": float("inf"), "epoch": 0})
    best_state: dict[str, torch.Tensor] | None = None  # the kept epoch's weights (also in the checkpoint)
    elapsed: float = 0.0

    def keep_weights(self) -> None:
        """Hold a copy of the model's weights as the best epoch's."""
        self.best_state = {k: v.detach().to("cpu", copy=True) for k, v in self.model.state_dict().items()}


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


def write_history(history: list[dict], csv_path: Path, png_path: Path, title: str) -> None:
    """The per-epoch rows as CSV and the train/validation MSE curves as a plot."""
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


def warm_start_state(path: Path, model: CompletionNet) -> tuple[list[dict], dict, float]:
    """Load the weights file ``path`` into ``model``; return the history of its run up to the
    epoch of those weights (``<stem>.csv`` beside it), the best entry and the elapsed seconds.

    Raises:
        ValueError: missing or unreadable file or CSV, another architecture, or a file without
            the epoch of its weights (not written by :func:`~nbv_prob_cnn.completion.train.train`).
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


def save_checkpoint(path: Path, state: RunState, run_config: dict) -> None:
    """The resumable ``<stem>.last.ckpt``: the last epoch's model and optimizer, the run's settings,
    history and best entry, and the best epoch's weights (written to a temporary file, then moved)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save(
        {
            "model": state.model.state_dict(),
            "optimizer": state.optimizer.state_dict(),
            "model_config": state.model.config(),
            "run_config": run_config,
            "history": state.history,
            "best": state.best,
            "elapsed_s": state.elapsed,
            "best_model": state.best_state,
        },
        tmp,
    )
    os.replace(tmp, path)


def load_checkpoint(path: Path, state: RunState, run_config: dict) -> None:
    """Continue ``state`` from the checkpoint ``path`` of the same run.

    Raises:
        ValueError: the checkpoint is of another run configuration or architecture.
    """
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    if ckpt.get("run_config") != run_config or ckpt.get("model_config") != state.model.config():
        raise ValueError(
            f"{path}: checkpoint of a different run configuration; "
            "pass --no-resume to start over or choose another --out"
        )
    state.model.load_state_dict(ckpt["model"])
    state.optimizer.load_state_dict(ckpt["optimizer"])
    state.history, state.best, state.elapsed = ckpt["history"], ckpt["best"], float(ckpt["elapsed_s"])
    state.best_state = ckpt.get("best_model")  # None in checkpoints written before it was stored
