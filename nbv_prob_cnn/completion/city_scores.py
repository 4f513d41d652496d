"""Scores of a City-CNN on validation/test examples, streamed one batch at a time
(outputs are not kept: a 3DU D-City-CNN output is 67 MB):

* **MSE** of ``output · mask`` against the target (the training loss), per example, averaged;
* the same MSE of two trivial predictors: the **all-zero output** and the **mean target**
  (``mask · c`` with ``c`` the per-channel mean of the training targets over the cells the masks
  keep, :func:`mean_target_per_channel`);
* **Spearman ρ** between prediction and target per grid, averaged over grids: over the view
  gains of every (empty lattice cell, view) pair for Flat and D-City-CNN (decoded as the planner
  decodes them, :func:`~nbv_prob_cnn.planners.city_cnn.decode_views`), over the best view's gain
  (the vector norm) of every empty lattice cell for B-City-CNN. Grids where either side is
  constant have no ρ and are left out of the mean.
* **cell ρ**, the same for all three variants: Spearman ρ between the predicted and the target
  gain of each empty lattice cell's best view (decoded, the largest view gain per cell), across
  cells. For B-City-CNN it equals ρ (one gain per cell); for Flat and D-City-CNN ρ also counts
  the ranking of the views inside each cell, cell ρ only the ranking of the cells, which is what
  a planner taking the best (cell, view) pair needs besides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from nbv_prob_cnn.basics.datasets import DatasetSpec
from nbv_prob_cnn.basics.grid import lattice_index
from nbv_prob_cnn.basics.rank_stats import spearman as spearman  # re-exported
from nbv_prob_cnn.completion.tasks import Example


def mean_target_per_channel(examples: Sequence[Example]) -> np.ndarray:
    """``(C,)`` mean target per channel over the cells the masks keep (0 where none is kept)."""
    total: np.ndarray | None = None
    count = 0.0
    for e in examples:
        keep = np.broadcast_to(e.mask, e.target.shape) > 0
        sums = np.where(keep, e.target, 0.0).reshape(e.target.shape[0], -1).sum(axis=1, dtype=np.float64)
        total = sums if total is None else total + sums
        count += float(keep[0].sum())
    if total is None or count == 0:
        raise ValueError("examples: no kept cell to take a mean target from")
    return (total / count).astype(np.float32)


def _decoded_views(
    method: str, spec: DatasetSpec, output: np.ndarray, example: Example
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The empty lattice cells ``(N, dims)`` of an example and the predicted and target view gains
    ``(N, V)`` there, decoded as the planner decodes them."""
    from nbv_prob_cnn.planners.city_cnn import CityGeometry, decode_views

    s = CityGeometry.of(method, spec).stride
    empty = example.inputs[0] > 0
    cells = np.argwhere(empty[lattice_index(empty.ndim, s)])
    origins = cells * s
    return (
        cells,
        decode_views(method, output, empty, spec, origins),
        decode_views(method, example.target, empty, spec, origins),
    )


Pairs = tuple[np.ndarray, np.ndarray]


def rank_pairs(method: str, spec: DatasetSpec, output: np.ndarray, example: Example) -> tuple[Pairs, Pairs]:
    """``(gain pairs, cell pairs)``: the predicted and target values whose agreement ρ and cell ρ
    measure (see module docs), from one decoding of the output and the target."""
    cells, predicted, target = _decoded_views(method, spec, output, example)
    best = (predicted.max(axis=1, initial=0.0), target.max(axis=1, initial=0.0))
    if method == "b_city_cnn":
        index = (slice(None), *cells.T)
        return (np.linalg.norm(output[index], axis=0), np.linalg.norm(example.target[index], axis=0)), best
    return (predicted.ravel(), target.ravel()), best


def gain_pairs(method: str, spec: DatasetSpec, output: np.ndarray, example: Example) -> Pairs:
    """Predicted and target gains whose rank agreement ρ measures (see module docs)."""
    return rank_pairs(method, spec, output, example)[0]


def cell_gain_pairs(method: str, spec: DatasetSpec, output: np.ndarray, example: Example) -> Pairs:
    """Predicted and target gain of the best view of every empty lattice cell (cell ρ, see module
    docs), decoded as the planner decodes them."""
    return rank_pairs(method, spec, output, example)[1]


@dataclass(frozen=True)
class CityScores:
    """Scores of a network on a list of examples (see module docs)."""

    mse: float
    zero_mse: float
    mean_mse: float
    rho: float  # mean over grids with a defined ρ
    rho_grids: int  # how many grids have one
    n: int
    cell_rho: float = float("nan")  # mean over grids with a defined cell ρ


def score_city(
    model: torch.nn.Module,
    method: str,
    spec: DatasetSpec,
    examples: Sequence[Example],
    mean_target: np.ndarray,
    device: torch.device,
    batch: int,
) -> CityScores:
    """Score ``model`` on ``examples`` (built batch by batch, see module docs)."""
    model.eval()
    mse, zero, mean, rhos, cell_rhos = [], [], [], [], []
    c = torch.as_tensor(mean_target, dtype=torch.float32)
    with torch.inference_mode():
        for start in range(0, len(examples), batch):
            for e in examples[start : start + batch]:  # shapes may differ between grids
                x = torch.as_tensor(e.inputs[None], dtype=torch.float32, device=device)
                target = torch.as_tensor(e.target, dtype=torch.float32)
                mask = torch.as_tensor(e.mask, dtype=torch.float32)
                out = (model(x)[0].float().cpu() * mask).numpy()
                mse.append(float(np.mean((out - e.target) ** 2)))
                zero.append(float(torch.mean(target**2)))
                constant = mask * c.reshape(-1, *([1] * (target.ndim - 1)))
                mean.append(float(torch.mean((constant - target) ** 2)))
                gains, best = rank_pairs(method, spec, out, e)
                rhos.append(spearman(*gains))
                cell_rhos.append(spearman(*best))
    defined = [r for r in rhos if np.isfinite(r)]
    cells_defined = [r for r in cell_rhos if np.isfinite(r)]
    return CityScores(
        float(np.mean(mse)) if mse else float("nan"),
        float(np.mean(zero)) if zero else float("nan"),
        float(np.mean(mean)) if mean else float("nan"),
        float(np.mean(defined)) if defined else float("nan"),
        len(defined),
        len(mse),
        float(np.mean(cells_defined)) if cells_defined else float("nan"),
    )
