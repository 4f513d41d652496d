"""Calibration of predicted occupancy probabilities: reliability table, expected calibration
error (ECE) and the reliability plot. Only unknown cells count (known cells are exact by
construction, ``P = U·P' + O``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

N_BINS = 10


@dataclass
class Reliability:
    """Per probability bin ``[k/N, (k+1)/N)`` (the last one closed): cells, mean predicted
    probability, observed occupied frequency; and the ECE = Σ cells/total · |observed − predicted|."""

    edges: np.ndarray
    counts: np.ndarray
    mean_predicted: np.ndarray
    observed: np.ndarray
    ece: float


def reliability(predicted: np.ndarray, occupied: np.ndarray, n_bins: int = N_BINS) -> Reliability:
    """Reliability of probabilities ``predicted`` against binary outcomes ``occupied`` (same shape).

    Raises:
        ValueError: different shapes, no sample, or probabilities outside [0, 1].
    """
    p = np.asarray(predicted, dtype=np.float64).ravel()
    y = np.asarray(occupied, dtype=np.float64).ravel()
    if p.shape != y.shape or p.size == 0:
        raise ValueError(f"predicted/occupied: expected equal non-empty sizes, got {p.size} and {y.size}")
    if not np.all(np.isfinite(p)) or p.min() < 0 or p.max() > 1:
        raise ValueError("predicted: probabilities must be finite and in [0, 1]")
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    index = np.minimum((p * n_bins).astype(np.int64), n_bins - 1)
    counts = np.bincount(index, minlength=n_bins).astype(np.int64)
    safe = np.maximum(counts, 1)
    mean_predicted = np.bincount(index, weights=p, minlength=n_bins) / safe
    observed = np.bincount(index, weights=y, minlength=n_bins) / safe
    ece = float(np.sum(counts / p.size * np.abs(observed - mean_predicted)))
    return Reliability(edges, counts, mean_predicted, observed, ece)


def save_reliability_plot(table: Reliability, path: str | Path, title: str) -> Path:
    """Reliability diagram (observed frequency against mean predicted probability per bin)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5, 5))
    ax = fig.add_subplot(1, 1, 1)
    used = table.counts > 0
    ax.plot([0, 1], [0, 1], "k--", lw=1, label="perfect calibration")
    ax.plot(table.mean_predicted[used], table.observed[used], "o-", label=f"model (ECE {table.ece:.4f})")
    ax.set_xlabel("predicted occupancy probability (unknown cells)")
    ax.set_ylabel("observed occupied fraction")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return Path(path)
