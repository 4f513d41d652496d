"""Time per City-CNN training step, examples ray-cast on the fly against read from the cached
training set (issue #21), with the same network, batch size, crops and torch threads.

    nbv study step_timing --dataset 3du --method d_city_cnn --steps 5

A step is: build the batch's examples (ray-cast targets, or read and assemble cached ones) and
one Adam step on them (:func:`~nbv_prob_cnn.completion.train.train_step`). The first step of each
source is a warm-up and not timed. The training environments used are the first ``--envs``;
their cache chunks are generated first when missing (not timed).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from nbv_prob_cnn.basics.datasets import dataset_spec
from nbv_prob_cnn.completion.city_cache import CachedCityExamples, CacheLayout, ensure_chunks
from nbv_prob_cnn.completion.data import crop_box, load_or_generate_sample, rotations
from nbv_prob_cnn.completion.tasks import TrainingTask
from nbv_prob_cnn.completion.train_steps import start_at_mean_target, train_step


def time_steps(dataset: str, method: str, steps: int, envs: int, cached: bool, seed: int = 0) -> dict[str, float]:
    """Mean seconds per step (``examples``, ``network``, ``total``) over ``steps`` timed steps."""
    spec = dataset_spec(dataset)
    task = TrainingTask(method, spec)
    crop, batch = spec.training.crop, spec.training.batch_size
    seeds = list(spec.train_seeds[:envs])
    rots = rotations(dataset)
    if cached:
        layout = CacheLayout.for_training(dataset, crop, spec.training.test_crop)
        ensure_chunks(layout, {"train": seeds}, progress=False)
        source = CachedCityExamples(method, layout, seeds, [], [], crop)
    else:
        samples = [load_or_generate_sample(dataset, s) for s in seeds]

    def example(item: int, rng: np.random.Generator):
        index, k = item // len(rots), item % len(rots)
        if cached:
            return source.train_example(index, k, rng)
        state, truth = rots[k].apply(samples[index].state), rots[k].apply(samples[index].truth)
        return task.example(state, truth, crop_box(state.shape, crop, rng, task.align))

    torch.manual_seed(seed)
    model = task.build()
    rng = np.random.default_rng([seed, 1])
    order = rng.permutation(len(seeds) * len(rots))
    if model.head == "sigmoid":
        start_at_mean_target(model, [example(int(i), rng) for i in order[:batch]])
    optimizer = torch.optim.Adam(model.parameters(), lr=spec.training.lr)
    t_examples, t_network = [], []
    for step in range(steps + 1):
        items = [int(order[(step * batch + j) % order.size]) for j in range(batch)]
        t0 = time.perf_counter()
        examples = [example(i, rng) for i in items]
        t1 = time.perf_counter()
        train_step(model, optimizer, examples, torch.device("cpu"))
        t2 = time.perf_counter()
        if step:  # the first step warms up
            t_examples.append(t1 - t0)
            t_network.append(t2 - t1)
    return {
        "examples": float(np.mean(t_examples)),
        "network": float(np.mean(t_network)),
        "total": float(np.mean(t_examples) + np.mean(t_network)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True, choices=["2d", "3du", "3dt"])
    parser.add_argument("--method", required=True, choices=["flat_city_cnn", "b_city_cnn", "d_city_cnn"])
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--envs", type=int, default=4)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    for name, cached in (("on the fly", False), ("cached", True)):
        t = time_steps(args.dataset, args.method, args.steps, args.envs, cached)
        print(
            f"{args.dataset} {args.method} {name}: {t['total']:.3f} s/step "
            f"(examples {t['examples']:.3f} s, network {t['network']:.3f} s; batch "
            f"{dataset_spec(args.dataset).training.batch_size}, {args.threads} thread(s), {args.steps} steps)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
