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

Run: ``python -m nbv_prob_cnn.completion.b_city_targets --dataset 3dt``
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter

from nbv_prob_cnn.completion.city_scores import spearman


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


def measure(dataset: str) -> TargetAgreement:
    """:class:`TargetAgreement` of B-City-CNN's targets on the data set's cached validation grids."""
    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout, ensure_chunks
    from nbv_prob_cnn.planners.city_cnn import CityGeometry

    spec = dataset_spec(dataset)
    seeds = list(spec.validation_seeds)
    layout = CacheLayout.for_training(dataset, spec.training.crop, spec.training.test_crop)
    ensure_chunks(layout, {"train": list(spec.train_seeds), "eval": seeds}, progress=True)
    examples = CachedCityExamples("b_city_cnn", layout, list(spec.train_seeds), seeds, [], spec.training.crop)
    stride = CityGeometry.of("b_city_cnn", spec).stride
    rhos = []
    for example in examples.fixed(seeds):
        empty = example.inputs[0] > 0
        lattice = empty[tuple(slice(None, None, stride) for _ in range(empty.ndim))]
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
