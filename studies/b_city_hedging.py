"""B-City-CNN's loss rewards hedging (issue #21): what the MSE on B-City-CNN's vector targets
prefers, measured with the predictions of a Flat City-CNN on the same grids.

B-City-CNN regresses, per empty lattice cell, the best view's gain times the view's unit
direction (:func:`~nbv_prob_cnn.planners.city_cnn.assemble_city_target`); the planner reads the
gain back as the vector's norm. A Flat City-CNN predicts every view's gain, so its output can be
turned into B vectors in more than one way. :func:`hedged_vectors` spans them with a temperature
``k`` (in units of the standard deviation of the Flat output over the grid's kept cells):

* ``k = 0``: the hard decision, the best predicted view's gain times its direction (the norm
  ranks the cells exactly as the Flat network's best views do);
* ``k > 0``: the mean of ``gain_v · u_v`` over the views, weighted by a softmax of the predicted
  gains at temperature ``k · std``: the output of a network that hedges between views it cannot
  tell apart, whose norm shrinks where the directions spread.

:func:`hedging_tradeoff` scores each on the validation grids: the B-target MSE (the B network's
training loss) and the cell ρ (:mod:`~nbv_prob_cnn.completion.city_scores`), beside the mean
target and, when given, trained B-City-CNN weights. If the loss falls as ``k`` grows while the
cell ρ falls with it, training B-City-CNN by MSE moves it away from ranking the cells.

Run: ``nbv study b_city_hedging --dataset 3du --out docs/b_city_hedging_3du``
(writes ``.csv`` and ``.png``).
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nbv_prob_cnn.basics.datasets import DatasetSpec
from nbv_prob_cnn.basics.grid import lattice_index
from nbv_prob_cnn.completion.city_scores import spearman
from nbv_prob_cnn.completion.tasks import Example

#: Temperatures of :func:`hedging_tradeoff` (0: the hard decision).
TEMPERATURES = (0.0, 0.1, 0.3, 1.0, 3.0, 10.0, 100.0)

#: The temperature key of the reference predictors while scores are collected (NaN cannot be a
#: dictionary key: it equals nothing, itself included).
_REFERENCE = -1.0


def hedged_vectors(flat_output: np.ndarray, unit: np.ndarray, temperature: float) -> np.ndarray:
    """B vectors ``(C, *lattice)`` from a Flat City-CNN output ``(V, *lattice)`` (view gains)
    and the views' unit vectors ``(V, C)``: the best view's gain times its vector at
    ``temperature`` 0, else ``sum_v softmax(gain / temperature)_v · gain_v · u_v``."""
    if temperature < 0:
        raise ValueError(f"temperature: expected >= 0, got {temperature}")
    if temperature == 0:
        best = flat_output.argmax(axis=0)
        return np.moveaxis(unit[best], -1, 0) * flat_output.max(axis=0)[None]
    logits = (flat_output - flat_output.max(axis=0, keepdims=True)) / temperature
    weights = np.exp(logits)
    weights /= weights.sum(axis=0, keepdims=True)
    return np.einsum("v...,vc->c...", weights * flat_output, unit)


@dataclass(frozen=True)
class HedgeScore:
    """Mean over validation grids of one B predictor's B-target MSE and cell ρ."""

    name: str
    temperature: float  # NaN for the reference predictors
    mse: float
    cell_rho: float


def _cell_norms(vectors: np.ndarray, cells: np.ndarray) -> np.ndarray:
    return np.linalg.norm(vectors[(slice(None), *cells.T)], axis=0)


def hedging_tradeoff(
    spec: DatasetSpec,
    flat_model: torch.nn.Module,
    flat_examples: Sequence[Example],
    b_examples: Sequence[Example],
    mean_target: np.ndarray,
    b_model: torch.nn.Module | None = None,
    temperatures: Sequence[float] = TEMPERATURES,
) -> list[HedgeScore]:
    """:class:`HedgeScore` of the hedged Flat outputs at each temperature (module docs), of the
    mean target and of ``b_model``, on the same grids (``flat_examples[i]`` and ``b_examples[i]``
    hold the same state)."""
    from nbv_prob_cnn.planners.city_cnn import CityGeometry, _view_vectors

    unit = _view_vectors(spec).astype(np.float32)
    stride = CityGeometry.of("b_city_cnn", spec).stride
    rows: dict[tuple[str, float], list[tuple[float, float]]] = {}
    flat_model.eval()
    if b_model is not None:
        b_model.eval()
    for flat_example, b_example in zip(flat_examples, b_examples, strict=True):
        x = torch.as_tensor(flat_example.inputs[None], dtype=torch.float32)
        with torch.inference_mode():
            flat = flat_model(x)[0].float().numpy() * flat_example.mask
            b_out = b_model(x)[0].float().numpy() * b_example.mask if b_model is not None else None
        empty = b_example.inputs[0] > 0
        cells = np.argwhere(empty[lattice_index(empty.ndim, stride)])
        target_norms = _cell_norms(b_example.target, cells)
        spread = float(flat[:, empty[lattice_index(empty.ndim, stride)]].std()) or 1.0
        predictors: dict[tuple[str, float], np.ndarray] = {
            ("hedged Flat City-CNN", k): hedged_vectors(flat, unit, k * spread) * b_example.mask for k in temperatures
        }
        predictors[("mean target", _REFERENCE)] = b_example.mask * mean_target.reshape(-1, *([1] * empty.ndim))
        if b_out is not None:
            predictors[("B-City-CNN", _REFERENCE)] = b_out
        for key, vectors in predictors.items():
            mse = float(np.mean((vectors - b_example.target) ** 2))
            rows.setdefault(key, []).append((mse, spearman(_cell_norms(vectors, cells), target_norms)))
    out = []
    for (name, k), values in rows.items():
        mses = [m for m, _ in values]
        rhos = [r for _, r in values if np.isfinite(r)]
        temperature = float("nan") if k == _REFERENCE else k
        out.append(HedgeScore(name, temperature, float(np.mean(mses)), float(np.mean(rhos)) if rhos else float("nan")))
    return out


def write_outputs(scores: Sequence[HedgeScore], out: Path, title: str) -> None:
    """``out.csv`` (one row per predictor) and ``out.png`` (MSE and cell ρ against temperature)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["predictor", "temperature_in_std", "b_target_mse", "cell_rho"])
        for s in scores:
            writer.writerow(
                [s.name, "" if np.isnan(s.temperature) else s.temperature, f"{s.mse:.6g}", f"{s.cell_rho:.4f}"]
            )
    from matplotlib.figure import Figure

    hedged = [s for s in scores if not np.isnan(s.temperature)]
    x = [max(s.temperature, 0.03) for s in hedged]  # k = 0 drawn at 0.03 on the log axis
    fig = Figure(figsize=(7, 4))
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(x, [s.mse for s in hedged], marker="o", color="tab:blue", label="hedged Flat City-CNN: B-target MSE")
    ax.set_xscale("log")
    ax.set_xlabel("softmax temperature (std of the Flat output; 0.03 = hard argmax)")
    ax.set_ylabel("B-target MSE (validation grids)")
    ax2 = ax.twinx()
    ax2.plot(x, [s.cell_rho for s in hedged], marker="s", color="tab:red", label="hedged Flat City-CNN: cell ρ")
    ax2.set_ylabel("cell ρ (Spearman, best view gain per cell)")
    colours = {"mean target": "tab:gray", "B-City-CNN": "tab:green"}
    for s in scores:
        if s.name in colours:
            ax.axhline(s.mse, color=colours[s.name], linestyle="--", label=f"{s.name}: MSE")
            if np.isfinite(s.cell_rho):
                ax2.axhline(s.cell_rho, color=colours[s.name], linestyle=":", label=f"{s.name}: cell ρ")
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=7, loc="best")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=100)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="B-target MSE and cell rho of hedged Flat City-CNN outputs")
    parser.add_argument("--dataset", required=True, choices=["2d", "3du", "3dt"])
    parser.add_argument("--flat-weights", default=None, help="Flat City-CNN weights (default: the shipped ones)")
    parser.add_argument("--b-weights", default=None, help="B-City-CNN weights to compare (default: the shipped ones)")
    parser.add_argument("--out", required=True, help="output path without suffix (.csv and .png are written)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout, ensure_chunks
    from nbv_prob_cnn.completion.city_scores import mean_target_per_channel
    from nbv_prob_cnn.completion.inference import load_model

    spec = dataset_spec(args.dataset)
    train_seeds, seeds = list(spec.train_seeds), list(spec.validation_seeds)
    layout = CacheLayout.for_training(args.dataset, spec.training.crop, spec.training.test_crop)
    ensure_chunks(layout, {"train": train_seeds, "eval": seeds}, progress=True)
    flat = CachedCityExamples("flat_city_cnn", layout, train_seeds, seeds, [], spec.training.crop)
    b = CachedCityExamples("b_city_cnn", layout, train_seeds, seeds, [], spec.training.crop)
    cpu = torch.device("cpu")
    scores = hedging_tradeoff(
        spec,
        load_model(args.flat_weights, args.dataset, cpu, model_name="flat_city_cnn"),
        flat.fixed(seeds),  # built lazily, one grid at a time
        b.fixed(seeds),
        mean_target_per_channel(b.unrotated_training()),
        load_model(args.b_weights, args.dataset, cpu, model_name="b_city_cnn"),
    )
    for s in scores:
        k = "" if np.isnan(s.temperature) else f" k={s.temperature:g}"
        print(f"{args.dataset} {s.name}{k}: B-target MSE {s.mse:.6f}, cell rho {s.cell_rho:+.3f}")
    write_outputs(scores, Path(args.out), f"{args.dataset}: B-City-CNN targets, {len(seeds)} validation grids")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
