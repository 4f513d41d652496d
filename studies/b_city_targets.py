"""Why B-City-CNN's predicted norm hardly ranks the cells (issue #21): a measurement on its own
targets, no network involved.

B-City-CNN regresses, per empty lattice cell, the vector ``g · d`` (``g`` the best view's gain,
``d`` its direction: a unit 2D vector or a ``w >= 0`` quaternion). Trained with MSE, a
convolutional network predicts about the mean of the targets it cannot tell apart; where the best
direction changes from cell to cell, that mean is shorter than ``g``. This module measures, on
the cached validation grids, how much of the gain ranking survives such averaging:

* ``rho_local_mean``: Spearman ρ between ``g`` and the norm of the mean target vector over the
  cell's ``3^d`` neighbourhood of empty lattice cells (what a predictor that is smooth at the
  lattice scale can reach at best);
* ``rho_consistency``: ρ between ``g`` and the neighbourhood's direction agreement (norm of the
  mean unit direction, 1 = all the same);
* ``rho_flat_max``: for reference, ρ between ``g`` and itself smoothed the same way (the mean of
  the neighbourhood's gains), which a Flat City-CNN-like output keeps.

A second measurement (:func:`tie_agreement`) looks inside one cell instead, at the gains of all
candidate views there (the Flat City-CNN targets of the same states). Where several views come
within a fraction ``tie`` of the best one, a network that cannot tell which of them wins is best
off (in MSE) predicting the mean of their target vectors, ``g · |mean of their directions|``,
whose norm shrinks as the tied directions spread. ``rho_tied_mean`` is the ρ between ``g`` and
that norm, ``rho_ties`` the ρ between ``g`` and the number of tied views.

Run: ``nbv study b_city_targets --dataset 3dt``
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.ndimage import uniform_filter

from nbv_prob_cnn.basics.grid import lattice_index
from nbv_prob_cnn.completion.city_scores import spearman

if TYPE_CHECKING:
    from nbv_prob_cnn.completion.tasks import Example


@dataclass(frozen=True)
class TargetAgreement:
    """Mean over grids of the three ρ of the module doc, and the grids they come from."""

    rho_local_mean: float
    rho_consistency: float
    rho_flat_max: float
    grids: int


def neighbourhood_mean(values: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Mean of ``values (C, *spatial)`` over each cell's ``3^d`` neighbourhood, counting only
    cells where ``keep (*spatial)`` is set (0 where none is)."""
    weight = uniform_filter(keep.astype(np.float64), size=3, mode="constant")
    sums = np.stack([uniform_filter(np.where(keep, v, 0.0), size=3, mode="constant") for v in values])
    return np.where(weight > 0, sums / np.maximum(weight, 1e-12), 0.0)


def grid_agreement(target: np.ndarray, empty_lattice: np.ndarray) -> tuple[float, float, float]:
    """The three ρ of one grid's target ``(C, *lattice)`` over its empty lattice cells."""
    gain = np.linalg.norm(target, axis=0)
    keep = empty_lattice & (gain > 0)
    direction = np.where(keep, target / np.maximum(gain, 1e-12), 0.0)
    local = np.linalg.norm(neighbourhood_mean(target, keep), axis=0)
    consistency = np.linalg.norm(neighbourhood_mean(direction, keep), axis=0)
    flat = neighbourhood_mean(gain[None], keep)[0]
    cells = empty_lattice
    return (
        spearman(gain[cells], local[cells]),
        spearman(gain[cells], consistency[cells]),
        spearman(gain[cells], flat[cells]),
    )


def validation_lattices(dataset: str, method: str) -> Iterator[tuple[Example, np.ndarray]]:
    """The data set's cached validation examples of City-CNN ``method`` (the cache is built first
    where it is missing), each with its empty cells on the method's lattice."""
    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout, ensure_chunks
    from nbv_prob_cnn.planners.city_cnn import CityGeometry

    spec = dataset_spec(dataset)
    seeds = list(spec.validation_seeds)
    layout = CacheLayout.for_training(dataset, spec.training.crop, spec.training.test_crop)
    ensure_chunks(layout, {"train": list(spec.train_seeds), "eval": seeds}, progress=True)
    examples = CachedCityExamples(method, layout, list(spec.train_seeds), seeds, [], spec.training.crop)
    stride = CityGeometry.of(method, spec).stride
    for example in examples.fixed(seeds):
        empty = example.inputs[0] > 0
        yield example, empty[lattice_index(empty.ndim, stride)]


def tied_view_norms(view_gains: np.ndarray, unit: np.ndarray, tie: float) -> tuple[np.ndarray, np.ndarray]:
    """For cells' view gains ``(N, V)`` and the views' unit vectors ``(V, C)`` (B-City-CNN's
    convention): the norm of ``g · mean(u_v over the tied views)`` (views with a gain of at least
    ``(1 - tie) · g``, ``g`` the best gain) and the number of tied views, both ``(N,)``."""
    best = view_gains.max(axis=1, keepdims=True)
    tied = (view_gains >= (1.0 - tie) * best) & (best > 0)
    count = tied.sum(axis=1)
    mean = (tied.astype(np.float64) @ unit) / np.maximum(count, 1)[:, None]
    return best[:, 0] * np.linalg.norm(mean, axis=1), count


@dataclass(frozen=True)
class TieAgreement:
    """Mean over grids of ρ(g, |tied mean vector|) and ρ(g, tied views), and the median number
    of tied views, at one tie fraction."""

    tie: float
    rho_tied_mean: float
    rho_ties: float
    median_ties: float
    grids: int


def tie_agreement(dataset: str, ties: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2)) -> list[TieAgreement]:
    """:class:`TieAgreement` per tie fraction on the data set's cached validation grids, from
    their Flat City-CNN targets (the gain of every candidate view per lattice cell)."""
    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.planners.city_cnn import _view_vectors

    unit = _view_vectors(dataset_spec(dataset)).astype(np.float64)
    rows: dict[float, list[tuple[float, float, float]]] = {t: [] for t in ties}
    for example, lattice in validation_lattices(dataset, "flat_city_cnn"):
        cells: tuple[slice | np.ndarray, ...] = (slice(None), *np.nonzero(lattice))
        views = example.target[cells].T.astype(np.float64)  # (N, V)
        gain = views.max(axis=1)
        for t in ties:
            norm, count = tied_view_norms(views, unit, t)
            rows[t].append((spearman(gain, norm), spearman(gain, count.astype(np.float64)), float(np.median(count))))
    out = []
    for t in ties:
        values = np.array(rows[t], dtype=np.float64)
        defined = np.all(np.isfinite(values), axis=1)
        mean = values[defined].mean(axis=0)
        out.append(TieAgreement(t, float(mean[0]), float(mean[1]), float(mean[2]), int(defined.sum())))
    return out


def measure(dataset: str) -> TargetAgreement:
    """:class:`TargetAgreement` of B-City-CNN's targets on the data set's cached validation grids."""
    rhos = []
    for example, lattice in validation_lattices(dataset, "b_city_cnn"):
        rhos.append(grid_agreement(example.target, lattice))
    values = np.array(rhos, dtype=np.float64)
    defined = np.all(np.isfinite(values), axis=1)
    mean = values[defined].mean(axis=0)
    return TargetAgreement(float(mean[0]), float(mean[1]), float(mean[2]), int(defined.sum()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="How much of B-City-CNN's gain ranking survives local averaging")
    parser.add_argument("--dataset", required=True, choices=["2d", "3du", "3dt"])
    args = parser.parse_args(argv)
    a = measure(args.dataset)
    print(
        f"{args.dataset} b_city_cnn targets, {a.grids} validation grids: rho(gain, |local mean vector|) "
        f"{a.rho_local_mean:.4f}; rho(gain, direction agreement) {a.rho_consistency:.4f}; "
        f"rho(gain, local mean gain) {a.rho_flat_max:.4f}"
    )
    for t in tie_agreement(args.dataset):
        print(
            f"{args.dataset} views within {t.tie:.0%} of the best ({t.grids} grids): median {t.median_ties:g} tied "
            f"views; rho(gain, |gain x mean tied direction|) {t.rho_tied_mean:.4f}; "
            f"rho(gain, tied views) {t.rho_ties:.4f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
