"""Score City-CNN weights (default: the shipped ones) on the validation grids of their data set:
MSE against the all-zero and mean-target baselines, pair rho and cell rho
(``nbv study city_scores --dataset D --method M [--weights W]``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from nbv_prob_cnn.completion.city_scores import CityScores, mean_target_per_channel, score_city


def score_weights(
    dataset: str, method: str, weights: str | None, seeds: Sequence[int] | None = None, progress: bool = True
) -> tuple[CityScores, dict[str, Any]]:
    """Scores of a City-CNN weights file (default: the shipped one) on the validation grids
    (or ``seeds``) of the cached training set (generated where missing), with the mean target
    of the cached training examples; returns them and the weights' model card."""
    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout, ensure_chunks
    from nbv_prob_cnn.completion.inference import load_model

    spec = dataset_spec(dataset)
    seeds = list(spec.validation_seeds if seeds is None else seeds)
    layout = CacheLayout.for_training(dataset, spec.training.crop, spec.training.test_crop)
    train_seeds = list(spec.train_seeds)
    ensure_chunks(layout, {"train": train_seeds, "eval": seeds}, progress=progress)
    examples = CachedCityExamples(method, layout, train_seeds, seeds, [], spec.training.crop)
    model = load_model(weights, dataset, torch.device("cpu"), model_name=method)
    mean = mean_target_per_channel(examples.unrotated_training())
    scores = score_city(model, method, spec, examples.fixed(seeds), mean, torch.device("cpu"), 1)
    return scores, dict(getattr(model, "card", {}) or {})


def main(argv: list[str] | None = None) -> int:
    """``nbv study city_scores --dataset D --method M [--weights W]``."""
    import argparse

    parser = argparse.ArgumentParser(description="Score City-CNN weights on the validation grids (MSE, baselines, rho)")
    parser.add_argument("--dataset", required=True, choices=["2d", "3du", "3dt"])
    parser.add_argument("--method", required=True, choices=["flat_city_cnn", "b_city_cnn", "d_city_cnn"])
    parser.add_argument("--weights", default=None, help="weights file (default: the shipped one)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    s, _ = score_weights(args.dataset, args.method, args.weights)
    print(
        f"{args.dataset} {args.method} {args.weights or 'shipped'}: validation MSE {s.mse:.6g} (all-zero "
        f"{s.zero_mse:.6g}, mean target {s.mean_mse:.6g}), Spearman rho {s.rho:.4f} ({s.rho_grids} of {s.n} grids), "
        f"cell rho {s.cell_rho:.4f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
