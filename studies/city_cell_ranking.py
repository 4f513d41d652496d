"""Why the City-CNNs do not rank the cells (issue #21): the cell ρ of trained weights on their own
training crops and on the validation grids, and how much of a cell's best view gain simple local
features of the state explain.

A planner built on a City-CNN takes the best (cell, view) pair of the whole grid, so the network
must rank the cells, not only the views inside each cell. :mod:`~nbv_prob_cnn.completion.city_scores`
measures both (ρ over all pairs, cell ρ over each cell's best view). This module adds two
measurements that tell a network that has not learnt the cell ranking from a target that holds
little of it:

* :func:`fit_and_generalisation`: pair ρ and cell ρ of a weights file on random training crops
  (unrotated, as training draws them) beside the same on the validation grids. A cell ρ near 0
  on the training crops too means the network did not fit the ranking, rather than failed to
  carry it to new grids.
* :func:`inside_crop_agreement`: on training crops, ρ between the targets training uses (rays
  cast through the whole grid) and the targets of the crop alone (rays cast inside it), per
  cell (best view) and per (cell, view) pair. What the second ranks is all a network shown only
  the crop can know; a low cell value means the crop's cell ranking is set mostly outside it.
* :func:`planner_rank_agreement`: the same two ρ for the view gains the ray-casting planners
  compute on the state (``prob_ig``: a constant ``P0`` in unknown cells; ``cnn_prob``: the
  completion CNN's probabilities) against the omniscient ones, on whole validation states: how
  much of the ranking a planner that looks at the state can reach without a City-CNN.
* :func:`feature_rank_agreement`: Spearman ρ, across the empty lattice cells of each validation
  grid, between the target's best view gain and local features of the input: height (last
  axis), distance to the nearest frontier cell, and the share of not-known-empty cells
  (unknown or occupied) and of frontier cells within a cube of side ``2r + 1`` around the cell.

Run: ``nbv study city_cell_ranking --dataset 3dt --method flat_city_cnn``
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import distance_transform_edt, uniform_filter

from nbv_prob_cnn.basics.datasets import DatasetSpec
from nbv_prob_cnn.basics.grid import lattice_index
from nbv_prob_cnn.completion.city_scores import cell_gain_pairs, rank_pairs, spearman
from nbv_prob_cnn.completion.data import TrainingSample
from nbv_prob_cnn.completion.tasks import Example
from nbv_prob_cnn.planners.city_cnn import encode_city_input

#: Half sides (cells) of the neighbourhoods the share features count over.
RADII = (8, 24)


@dataclass(frozen=True)
class FitScores:
    """Mean pair ρ and cell ρ on training crops and on validation grids."""

    train_rho: float
    train_cell_rho: float
    validation_rho: float
    validation_cell_rho: float
    train_examples: int
    validation_examples: int


def local_features(example: Example, stride: int) -> dict[str, np.ndarray]:
    """Features of each empty lattice cell (``np.argwhere`` order) of an example's input."""
    empty = example.inputs[0] > 0
    frontier = example.inputs[1] > 0
    cells = np.argwhere(empty[lattice_index(empty.ndim, stride)]) * stride
    at = tuple(cells.T)
    features = {
        "height": cells[:, -1].astype(np.float64),
        "distance to frontier": distance_transform_edt(~frontier)[at] if frontier.any() else np.zeros(len(cells)),
    }
    for r in RADII:
        features[f"not-empty share r{r}"] = uniform_filter((~empty).astype(np.float64), 2 * r + 1, mode="constant")[at]
        features[f"frontier share r{r}"] = uniform_filter(frontier.astype(np.float64), 2 * r + 1, mode="constant")[at]
    return features


def feature_rank_agreement(method: str, spec: DatasetSpec, examples: Sequence[Example]) -> dict[str, float]:
    """Mean over ``examples`` of ρ(feature, target best view gain) across their empty lattice
    cells, per feature of :func:`local_features` (grids without a defined ρ left out)."""
    from nbv_prob_cnn.planners.city_cnn import CityGeometry

    stride = CityGeometry.of(method, spec).stride
    rows: dict[str, list[float]] = {}
    for e in examples:
        _, gain = cell_gain_pairs(method, spec, e.target, e)
        for name, values in local_features(e, stride).items():
            rows.setdefault(name, []).append(spearman(values, gain))
    return {name: _defined_mean(values) for name, values in rows.items()}


def _defined_mean(values: Sequence[float]) -> float:
    """Mean of the finite values (NaN when none is)."""
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def inside_crop_agreement(
    method: str, spec: DatasetSpec, samples: Sequence[TrainingSample], crops_per_sample: int, seed: int = 0
) -> tuple[float, float, int]:
    """Mean cell ρ and pair ρ between whole-grid and inside-crop targets (module docs) over
    ``crops_per_sample`` random training crops of each sample; returns them and the crop count."""
    from nbv_prob_cnn.completion.data import crop_box
    from nbv_prob_cnn.planners.city_cnn import CityGeometry, city_targets

    stride = CityGeometry.of(method, spec).stride
    rng = np.random.default_rng(seed)
    cells, pairs = [], []
    for sample in samples:
        for _ in range(crops_per_sample):
            box = crop_box(sample.state.shape, spec.training.crop, rng, stride)
            whole = city_targets(method, sample.state, sample.truth, spec, box)
            state, truth = np.ascontiguousarray(sample.state[box]), np.ascontiguousarray(sample.truth[box])
            inside = city_targets(method, state, truth, spec)
            example = Example(encode_city_input(state[None])[0].numpy(), whole, np.ones(1, np.float32))
            gains, best = rank_pairs(method, spec, inside, example)  # (inside-crop, whole-grid) pairs
            cells.append(spearman(*best))
            if method == "flat_city_cnn":
                pairs.append(spearman(*gains))
    return _defined_mean(cells), _defined_mean(pairs), len(cells)


def planner_rank_agreement(
    spec: DatasetSpec, samples: Sequence[TrainingSample], methods: Sequence[str] = ("prob_ig", "cnn_prob")
) -> dict[str, tuple[float, float]]:
    """Per method, the mean cell ρ and pair ρ between its view gains and the omniscient ones
    (:func:`~nbv_prob_cnn.planners.city_cnn.omniscient_ray_gains`, the City-CNN targets before
    scaling) at the Flat City-CNN's origins of each sample (module docs)."""
    from nbv_prob_cnn.basics.grid import probability_with_constant
    from nbv_prob_cnn.completion.inference import complete
    from nbv_prob_cnn.gain import ray_gains
    from nbv_prob_cnn.planners.city_cnn import CityGeometry, omniscient_ray_gains

    geometry = CityGeometry.of("flat_city_cnn", spec)
    rows: dict[str, list[tuple[float, float]]] = {m: [] for m in methods}
    for sample in samples:
        origins = geometry.origins(sample.state)
        target = omniscient_ray_gains(sample.state, sample.truth, geometry, origins) @ geometry.membership
        for method in methods:
            if method == "prob_ig":
                prob = probability_with_constant(sample.state, spec.p0)
            elif method == "cnn_prob":
                prob = complete(sample.state, dataset=spec.name)
            else:
                raise ValueError(f"methods: expected prob_ig or cnn_prob, got {method!r}")
            rays = ray_gains(sample.state, prob, geometry.directions, spec.sensor.r_max, origins)
            views = rays @ geometry.membership
            rows[method].append(
                (spearman(views.max(axis=1), target.max(axis=1)), spearman(views.ravel(), target.ravel()))
            )
    return {m: (_defined_mean([c for c, _ in v]), _defined_mean([p for _, p in v])) for m, v in rows.items()}


def _rhos(model: torch.nn.Module, method: str, spec: DatasetSpec, examples: Sequence[Example]) -> tuple[float, float]:
    pairs, cells = [], []
    with torch.inference_mode():
        for e in examples:
            out = model(torch.as_tensor(e.inputs[None], dtype=torch.float32))[0].float().numpy() * e.mask
            gains, best = rank_pairs(method, spec, out, e)
            pairs.append(spearman(*gains))
            cells.append(spearman(*best))
    return _defined_mean(pairs), _defined_mean(cells)


def fit_and_generalisation(
    model: torch.nn.Module,
    method: str,
    spec: DatasetSpec,
    train_example: Callable[[int, np.random.Generator], Example],
    n_train: int,
    validation: Sequence[Example],
    seed: int = 0,
) -> FitScores:
    """:class:`FitScores` of ``model`` on ``n_train`` training crops (``train_example(i, rng)``)
    and on the ``validation`` examples."""
    model.eval()
    rng = np.random.default_rng(seed)
    train = [train_example(i, rng) for i in range(n_train)]
    train_rho, train_cell = _rhos(model, method, spec, train)
    val_rho, val_cell = _rhos(model, method, spec, validation)
    return FitScores(train_rho, train_cell, val_rho, val_cell, len(train), len(validation))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Cell ranking of City-CNN weights and of their targets")
    parser.add_argument("--dataset", required=True, choices=["2d", "3du", "3dt"])
    parser.add_argument("--method", required=True, choices=["flat_city_cnn", "b_city_cnn", "d_city_cnn"])
    parser.add_argument("--weights", default=None, help="weights file (default: the shipped one)")
    parser.add_argument("--train-crops", type=int, default=20, help="training crops to score (first environments)")
    parser.add_argument("--inside-envs", type=int, default=8, help="training environments for the inside-crop targets")
    parser.add_argument("--planner-grids", type=int, default=10, help="validation states for the planners' rho")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout, ensure_chunks
    from nbv_prob_cnn.completion.data import load_or_generate_sample
    from nbv_prob_cnn.completion.inference import load_model

    spec = dataset_spec(args.dataset)
    train_seeds, seeds = list(spec.train_seeds)[: args.train_crops], list(spec.validation_seeds)
    layout = CacheLayout.for_training(args.dataset, spec.training.crop, spec.training.test_crop)
    ensure_chunks(layout, {"train": train_seeds, "eval": seeds}, progress=True)
    examples = CachedCityExamples(args.method, layout, train_seeds, seeds, [], spec.training.crop)
    validation = examples.fixed(seeds)  # built lazily, one grid at a time (a 3DU Flat target is 54 MB)
    model = load_model(args.weights, args.dataset, torch.device("cpu"), model_name=args.method)

    def crop(i: int, rng: np.random.Generator) -> Example:
        example = examples.train_example(i, 0, rng)
        assert example is not None
        return example

    fit = fit_and_generalisation(model, args.method, spec, crop, len(train_seeds), validation)
    print(
        f"{args.dataset} {args.method} {args.weights or 'shipped'}: pair rho / cell rho on {fit.train_examples} "
        f"training crops {fit.train_rho:.3f} / {fit.train_cell_rho:.3f}, on {fit.validation_examples} validation "
        f"grids {fit.validation_rho:.3f} / {fit.validation_cell_rho:.3f}"
    )
    if spec.training.crop is not None:
        samples = [load_or_generate_sample(args.dataset, s) for s in train_seeds[: args.inside_envs]]
        cell, pair, n = inside_crop_agreement(args.method, spec, samples, 2)
        print(
            f"{args.dataset} targets on {n} training crops of {spec.training.crop}: rho(whole-grid target, "
            f"inside-crop target) per cell {cell:.3f}, per (cell, view) {pair:.3f} (Flat City-CNN only)"
        )
    states = [load_or_generate_sample(args.dataset, s) for s in seeds[: args.planner_grids]]
    for method, (cell, pair) in planner_rank_agreement(spec, states).items():
        print(
            f"{args.dataset} {method} against the omniscient gains on {len(states)} validation states: cell rho "
            f"{cell:.3f}, pair rho {pair:.3f}"
        )
    for name, rho in feature_rank_agreement(args.method, spec, validation).items():
        print(f"{args.dataset} targets: rho(best view gain of a cell, {name}) {rho:+.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
