"""Planning-iteration benchmarks (``nbv bench``): one ``prob_ig`` iteration at ~50 %
explored on the default worlds, OpenCL kernel against the numpy reference in the same run."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.grid import probability_with_constant, unknown_fraction
from nbv_prob_cnn.observe import observe
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.planners.base import search_best_view
from nbv_prob_cnn.worlds.world import World


@dataclass(frozen=True)
class BenchCase:
    """One benchmark row: a data set and its number of ray sub-cells per side."""

    dataset: str
    n_rays: int | None = None

    @property
    def label(self) -> str:
        return f"{self.dataset.upper()} N_rays={self.n_rays}" if self.n_rays else self.dataset.upper()


DEFAULT_CASES = (BenchCase("2d", 16), BenchCase("3du", 4), BenchCase("3du", 16), BenchCase("3dt", 4))


@dataclass
class BenchResult:
    case: BenchCase
    unknown_fraction: float
    origins: int
    rays: int
    opencl_s: float
    numpy_s: float
    numpy_origins: int
    nominal_samples: int

    @property
    def speedup(self) -> float:
        return self.numpy_s / self.opencl_s

    @property
    def samples_per_s(self) -> float:
        return self.nominal_samples / self.opencl_s


def half_explored(world: World, context: PlanningContext, target: float = 0.5, max_views: int = 400) -> np.ndarray:
    """Merge random views (random empty cell, random candidate orientation) until the
    unknown fraction drops to ``target``."""
    state = np.full(world.shape, -1, dtype=np.int8)
    free = np.argwhere(world.ground_truth == 0)
    for _ in range(max_views):
        if unknown_fraction(state, world.ground_truth) <= target:
            break
        cell = free[context.rng.integers(free.shape[0])]
        orientation = context.orientations[context.rng.integers(context.orientations.shape[0])]
        observe(state, world.ground_truth, cell, orientation, context.active_sensor)
    return state


def _time(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def run_case(case: BenchCase, world: World, repeats: int = 3, numpy_origins: int = 3000) -> BenchResult:
    """Time one full ``prob_ig`` planning iteration on OpenCL and the same search with the
    numpy reference on (at most) ``numpy_origins`` origins, extrapolated linearly."""
    context = PlanningContext(
        _defaults(case.dataset), rng=np.random.default_rng(world.seed), n_rays=case.n_rays, backend="opencl"
    )
    state = half_explored(world, context)
    origins = context.candidate_origins(state)
    planner = make_planner("prob_ig")
    planner.plan(state, context)  # warm-up: kernel build, buffers
    opencl_s = _time(lambda: planner.plan(state, context), repeats)

    subset = origins[np.random.default_rng(0).permutation(origins.shape[0])[:numpy_origins]]
    numpy_context = PlanningContext(context.defaults, n_rays=case.n_rays, backend="numpy")

    def numpy_iteration():
        prob = probability_with_constant(state, context.defaults.p0)
        search_best_view(state, prob, subset, numpy_context)

    numpy_s = _time(numpy_iteration, 1) * origins.shape[0] / max(1, subset.shape[0])
    r_max = context.active_sensor.r_max
    rays = context.directions.shape[0]
    return BenchResult(
        case,
        unknown_fraction(state, world.ground_truth),
        origins.shape[0],
        rays,
        opencl_s,
        numpy_s,
        subset.shape[0],
        origins.shape[0] * rays * (r_max + 1),
    )


def _defaults(dataset: str):
    from nbv_prob_cnn.camera import dataset_defaults

    return dataset_defaults(dataset)


def format_table(results: list[BenchResult]) -> str:
    """Markdown table of the results."""
    lines = [
        "| case | unknown | origins | rays | OpenCL iteration (s) | numpy iteration (s) | speed-up | "
        "nominal samples/s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r.case.label} | {r.unknown_fraction:.2f} | {r.origins} | {r.rays} | {r.opencl_s:.3f} | "
            f"{r.numpy_s:.2f} | {r.speedup:.0f}× | {r.samples_per_s:.2e} |"
        )
    return "\n".join(lines)


def cnn_table(seed: int = 1000, repeats: int = 3) -> str:
    """CNN inference time and a full ``cnn_prob`` planning iteration (CNN + ray casting + views)
    per data set at ~50 % explored, next to ``prob_ig``; markdown table."""
    from nbv_prob_cnn.completion import complete
    from nbv_prob_cnn.worlds import load_or_generate

    lines = [
        "| data set | grid | CNN inference (s) | cnn_prob iteration (s) | prob_ig iteration (s) |",
        "|---|---|---|---|---|",
    ]
    for dataset in ("2d", "3du", "3dt"):
        world = load_or_generate(dataset, seed)
        context = PlanningContext(_defaults(dataset), rng=np.random.default_rng(seed), backend="opencl")
        state = half_explored(world, context)
        complete(state, dataset=dataset)  # warm-up: load the weights
        t_cnn = _time(lambda: complete(state, dataset=dataset), repeats)  # noqa: B023 - used right here
        cnn, constant = make_planner("cnn_prob"), make_planner("prob_ig")
        t_plan = _time(lambda: cnn.plan(state, context), repeats)  # noqa: B023
        t_constant = _time(lambda: constant.plan(state, context), repeats)  # noqa: B023
        shape = "×".join(map(str, world.shape))
        lines.append(f"| {dataset.upper()} | {shape} | {t_cnn:.3f} | {t_plan:.3f} | {t_constant:.3f} |")
    return "\n".join(lines)
