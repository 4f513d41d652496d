"""Planning-iteration benchmarks (``nbv bench``): one planning iteration at ~50 % explored on
the default worlds, measured side by side in one run for

* ``iteration``: the planner's whole iteration (probability map, CNN inference included for
  ``cnn_prob``, origins, view search);
* ``pruned``: its view search alone, the exact coarse-to-fine argmax
  (:func:`~nbv_prob_cnn.gain.best_origin_view`: block bounds, then exact gains only where a
  bound reaches the best gain found, and only of the views whose bound reaches it);
* ``all_views``: the same search evaluating every view of the origins it evaluates
  (``prune_views=False``, the previous pruned search);
* ``fused``: the exhaustive view search (``view_gain`` kernel on every origin, rays summed into
  views on the device);
* ``two_step``: the previous path, kept here only as a baseline (``baseline_ray_gain``: per-ray
  gains to memory, then an (origins × rays) @ (rays × views) product);
* ``naive``: one work-item per (origin, ray) marching a float position, stopping at the first
  occupied cell, then the same product. This is a simple kernel of our own, *not* the authors'
  scheme (their kernel never stops early and calls ``pow`` per sample; ``authors`` is that);
* ``authors``: our own kernel after the scheme of the authors' published code
  (``authors_ray_gain`` in ``baselines.cl``: one work-item per (origin, ray), every sample of the
  original variant's range marched, ``pow`` per sample, the original weights), then per view
  sum(hits) / sum(hits + miss) by two products on the host. It computes the ``original`` gain
  variant (:mod:`nbv_prob_cnn.gain.variant`), not the paper's: compare it with ``pruned_original``
  (our pruned search on the same variant) for equal results, with ``pruned``/``fused`` for the
  planners' path. Its cost is exactly linear in origins × rays, so it is timed on a random subset
  of at most ``authors_origins`` origins and extrapolated (like ``numpy``);
* ``pruned_original``: the planners' pruned search under the ``original`` variant;
* ``numpy``: the reference on a random subset of origins, extrapolated linearly.

Every variant gets the same grid, probabilities and origins. "Effective samples/s" counts the
nominal ``origins × rays × (R_max + 1)`` samples per second for every variant (the work an
exhaustive march would do), so its ratios are speed ratios. Peak memory is the tracemalloc peak
of Python/numpy allocations during the iteration plus the OpenCL buffers it allocates (on a CPU
device those live in host memory too); torch's allocations (the CNN) are not included.
"""

from __future__ import annotations

import functools
import time
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nbv_prob_cnn.basics.grid import probability_with_constant, unknown_fraction
from nbv_prob_cnn.gain import GainSettings, origin_view_gains
from nbv_prob_cnn.gain.directions import distance_weights, sample_offsets
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.planners.base import search_best_view, search_views
from nbv_prob_cnn.sensing.observe import observe
from nbv_prob_cnn.worlds.world import World

BASELINE_SOURCE = Path(__file__).with_name("baselines.cl")
#: Origins × rays per baseline launch (the previous planners' block size).
BASELINE_RAYS_PER_CALL = 8_000_000
VARIANTS = ("iteration", "pruned", "all_views", "fused", "two_step", "naive", "pruned_original", "authors", "numpy")
#: Origins the ``authors`` baseline is timed on (then extrapolated; its cost is linear in origins).
AUTHORS_ORIGINS = 20_000
#: Relative gain difference under which the authors' baseline's view counts as the same choice.
AUTHORS_TIE_MARGIN = 1e-5


@dataclass(frozen=True)
class BenchCase:
    """One benchmark row: data set, ray sub-cells per side, origin stride and method."""

    dataset: str
    n_rays: int | None = None
    stride: int = 1
    method: str = "prob_ig"

    @property
    def label(self) -> str:
        rays = f" N_rays={self.n_rays}" if self.n_rays else ""
        stride = f" stride {self.stride}" if self.stride > 1 else " all cells"
        return f"{self.dataset.upper()}{rays}{stride} {self.method}"


DEFAULT_CASES = (
    BenchCase("2d", 16),
    BenchCase("3du", 4),
    BenchCase("3du", 16),
    BenchCase("3dt", 4, 2, "cnn_prob"),
    BenchCase("3dt", 4, 1, "cnn_prob"),
)


@dataclass
class Timing:
    seconds: float  # best wall-clock time
    peak_bytes: int
    cpu_seconds: float = 0.0  # CPU time of the process (all threads) in the best run


@dataclass
class BenchResult:
    case: BenchCase
    unknown_fraction: float
    origins: int
    rays: int
    nominal_samples: int
    numpy_origins: int
    timings: dict[str, Timing] = field(default_factory=dict)
    same_best_view: bool = True
    same_pruned_view: bool = True  # the coarse-to-fine search chose the exhaustive search's view
    cnn_s: float = 0.0  # CNN inference alone (cnn_prob cases; included in the iteration)
    authors_origins: int = 0  # origins the authors' baseline was timed on
    authors_samples: int = 0  # origins × rays × samples of the original range (all origins)
    # on its subset, the authors' baseline chose our original-variant view, or one whose gain (ours)
    # is within a float32 rounding margin of our best (near ties: 2D prob_ig has thousands within 1e-6)
    same_authors_view: bool = True

    def samples_per_s(self, variant: str) -> float:
        nominal = self.authors_samples if variant in ("authors", "pruned_original") else self.nominal_samples
        return nominal / self.timings[variant].seconds


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
    """Best of ``repeats`` wall-clock times, each repeat marching its grid anew (:func:`_fresh_grid`)."""
    best = float("inf")
    for _ in range(repeats):
        _fresh_grid()
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _fresh_grid() -> None:
    """The ray caster keeps the last marched grid for the next launch on an equal grid (a search and
    its re-ranking); a repeat on the same grid would skip marching it, which no plan of an exploration
    does: drop it."""
    from nbv_prob_cnn.gain.opencl import forget_marched_grid

    forget_marched_grid()


def _measure(fn, repeats: int, device_bytes: int = 0) -> Timing:
    """Best of ``repeats`` wall-clock times (and the CPU time of that run, less sensitive to other
    processes on the machine), each repeat marching its grid anew; memory peak of the first run
    (tracemalloc)."""
    tracemalloc.start()
    best = Timing(float("inf"), 0)
    for run in range(max(1, repeats)):
        _fresh_grid()
        cpu, start = time.process_time(), time.perf_counter()
        fn()
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        if run == 0:
            best.peak_bytes = tracemalloc.get_traced_memory()[1] + device_bytes
            tracemalloc.stop()
        if wall < best.seconds:
            best.seconds, best.cpu_seconds = wall, cpu
    return best


@functools.lru_cache(maxsize=1)
def _baseline_kernels():
    from nbv_prob_cnn.basics.cl_device import cl_runtime

    runtime = cl_runtime()
    program = runtime.build(BASELINE_SOURCE)
    kernels = (runtime.cl.Kernel(program, name) for name in ("baseline_ray_gain", "naive_ray_gain", "authors_ray_gain"))
    return runtime, *kernels


def authors_ray_terms(
    state: np.ndarray, prob: np.ndarray, origins: np.ndarray, directions: np.ndarray, r_max: int, free_hits: bool
) -> tuple[np.ndarray, np.ndarray, int]:
    """Hits and hits + miss ``(N, R)`` of the ``authors_ray_gain`` baseline (the authors' scheme,
    on the original variant's range and weights; ``free_hits``: the CNN/oracle maps' ``(1 - p)``),
    and the bytes of its OpenCL buffers."""
    from nbv_prob_cnn.gain.marched_grid import encode_grid
    from nbv_prob_cnn.gain.variant import ORIGINAL_FOCAL, sample_count

    runtime, kernel = _baseline_kernels()[0], _baseline_kernels()[3]
    cl, mf = runtime.cl, runtime.cl.mem_flags
    code = np.ascontiguousarray(encode_grid(state, prob))
    shape3 = code.shape + (1,) * (3 - code.ndim)
    n, rays = origins.shape[0], directions.shape[0]
    table = np.zeros((rays, 3), dtype=np.float32)
    table[:, : state.ndim] = directions
    origins3 = np.zeros((n, 3), dtype=np.float32)
    origins3[:, : state.ndim] = origins
    hits, totals = np.empty((n, rays), dtype=np.float32), np.empty((n, rays), dtype=np.float32)
    if n == 0:
        return hits, totals, 0
    buffers = [cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a) for a in (code, origins3, table)]
    out = [cl.Buffer(runtime.context, mf.WRITE_ONLY, hits.nbytes) for _ in range(2)]
    kernel(runtime.queue, (n * rays,), None, buffers[0], *(np.int32(d) for d in shape3), buffers[1], np.int32(n),
           buffers[2], np.int32(rays), np.int32(sample_count("original", r_max)), np.float32(state.ndim - 1),
           np.float32(ORIGINAL_FOCAL), np.int32(free_hits), *out)  # fmt: skip
    cl.enqueue_copy(runtime.queue, hits, out[0])
    cl.enqueue_copy(runtime.queue, totals, out[1])
    runtime.queue.finish()
    return hits, totals, code.nbytes + origins3.nbytes + table.nbytes + 2 * hits.nbytes


def authors_view_search(
    state: np.ndarray, prob: np.ndarray, origins: np.ndarray, context: PlanningContext, free_hits: bool
) -> tuple[float, int, int]:
    """Best view with the ``authors`` baseline: its ray terms in blocks, per view sum(hits) /
    sum(hits + miss) (two products). Returns (best gain, flat best index, device bytes)."""
    rays = context.directions.shape[0]
    block = max(1, BASELINE_RAYS_PER_CALL // rays)
    best_gain, best_index, device_bytes = -1.0, -1, 0
    for begin in range(0, origins.shape[0], block):
        hits, totals, used = authors_ray_terms(
            state, prob, origins[begin : begin + block], context.directions, context.active_sensor.r_max, free_hits
        )
        device_bytes = max(device_bytes, used)
        num, den = hits @ context.membership, totals @ context.membership
        views = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0).ravel()
        i = int(np.argmax(views))
        if views[i] > best_gain:
            best_gain, best_index = float(views[i]), i + begin * context.membership.shape[1]
    return best_gain, best_index, device_bytes


def baseline_view_search(
    state: np.ndarray, prob: np.ndarray, origins: np.ndarray, context: PlanningContext, kernel: str
) -> tuple[float, int, int]:
    """Best view with a baseline kernel (``"two_step"`` or ``"naive"``): per-ray gains in
    blocks, each block @ membership. Returns (best gain, flat best index, device bytes)."""
    from nbv_prob_cnn.gain.marched_grid import encode_grid

    runtime, two_step, naive, _ = _baseline_kernels()
    cl, mf = runtime.cl, runtime.cl.mem_flags
    sensor = context.active_sensor
    code = np.ascontiguousarray(encode_grid(state, prob))
    shape3 = code.shape + (1,) * (3 - code.ndim)
    rays = context.directions.shape[0]
    inv_total = np.float32(1.0 / distance_weights(sensor.r_max, state.ndim).sum())
    code_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=code)
    if kernel == "two_step":
        offsets = sample_offsets(context.directions, sensor.r_max)
        table = np.zeros(offsets.shape[:2] + (3,), dtype=np.int16)
        table[..., : offsets.shape[2]] = offsets
    else:
        table = np.zeros((rays, 3), dtype=np.float32)
        table[:, : state.ndim] = context.directions
    table_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=table)
    block = max(1, BASELINE_RAYS_PER_CALL // rays)
    best_gain, best_index, device_bytes = -1.0, -1, code.nbytes + table.nbytes
    for begin in range(0, origins.shape[0], block):
        chunk = origins[begin : begin + block]
        n = chunk.shape[0]
        origins3 = np.zeros((n, 3), dtype=np.int32 if kernel == "two_step" else np.float32)
        origins3[:, : state.ndim] = chunk
        origin_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=origins3)
        out = np.empty((n, rays), dtype=np.float32)
        out_buf = cl.Buffer(runtime.context, mf.WRITE_ONLY, out.nbytes)
        device_bytes = max(device_bytes, code.nbytes + table.nbytes + origins3.nbytes + out.nbytes)
        dims = [np.int32(d) for d in shape3]
        if kernel == "two_step":
            two_step(runtime.queue, (n * rays,), None, code_buf, *dims, origin_buf, np.int32(n), table_buf,
                     np.int32(rays), np.int32(sensor.r_max + 1), np.int32(state.ndim - 1), inv_total,
                     np.float32(0.0), np.int32(0), np.float32(0.0), out_buf)  # fmt: skip
        else:
            naive(runtime.queue, (n * rays,), None, code_buf, *dims, origin_buf, np.int32(n), table_buf,
                  np.int32(rays), np.int32(sensor.r_max + 1), np.int32(state.ndim - 1), inv_total, out_buf)  # fmt: skip
        cl.enqueue_copy(runtime.queue, out, out_buf)
        views = (out @ context.membership).ravel()
        i = int(np.argmax(views))
        if views[i] > best_gain:
            best_gain, best_index = float(views[i]), i + begin * context.membership.shape[1]
    return best_gain, best_index, device_bytes


def fused_device_bytes(state: np.ndarray, origins: int, context: PlanningContext) -> int:
    """OpenCL buffers of one fused search: padded grid, offsets, view table, origins, output."""
    from nbv_prob_cnn.gain.opencl import VIEW_GAIN_ORIGINS_PER_LAUNCH
    from nbv_prob_cnn.planners.base import MAX_VIEWS_PER_CALL

    views = context.membership.shape[1]
    block = min(origins, MAX_VIEWS_PER_CALL // views, VIEW_GAIN_ORIGINS_PER_LAUNCH)
    grid = int(np.prod([s + 2 for s in state.shape]))
    offsets = context.directions.shape[0] * (context.active_sensor.r_max + 1)
    return 4 * (grid + offsets + block * (1 + views) + int(context.membership.sum()) + views + 1)


def run_case(
    case: BenchCase, world: World, repeats: int = 3, numpy_origins: int = 3000, authors_origins: int = AUTHORS_ORIGINS
) -> BenchResult:
    """Time one planning iteration of ``case.method`` with every variant (see module doc)."""
    context = PlanningContext(
        _defaults(case.dataset), rng=np.random.default_rng(world.seed), n_rays=case.n_rays, backend="opencl",
        origin_stride=case.stride,
    )  # fmt: skip
    state = half_explored(world, context)
    origins = context.candidate_origins(state)
    planner = make_planner(case.method)
    if case.method == "cnn_prob":
        from nbv_prob_cnn.completion import complete

        prob = complete(state, dataset=case.dataset)
        cnn_s = _time(lambda: complete(state, dataset=case.dataset), repeats)
    else:
        cnn_s = 0.0
        prob = probability_with_constant(state, context.defaults.p0)
    choice = planner.plan(state, context)  # warm-up: kernel build, weights, buffers
    rays = context.directions.shape[0]
    r_max = context.active_sensor.r_max
    result = BenchResult(
        case, unknown_fraction(state, world.ground_truth), origins.shape[0], rays,
        origins.shape[0] * rays * (r_max + 1), min(numpy_origins, origins.shape[0]), cnn_s=cnn_s,
    )  # fmt: skip
    n_views = context.membership.shape[1]
    fused_bytes = fused_device_bytes(state, origins.shape[0], context)
    result.timings["iteration"] = _measure(lambda: planner.plan(state, context), repeats, fused_bytes)
    # the coarse-to-fine search also holds the bound grid (padded grid + 2 guard slabs) and per-block bounds
    grid = int(np.prod([s + 2 for s in state.shape]))
    pruned_bytes = fused_bytes + 4 * (2 * grid + origins.shape[0] * (n_views + 1))
    found: dict[str, Any] = {}
    result.timings["pruned"] = _measure(
        lambda: found.setdefault("pruned", search_best_view(state, prob, origins, context)), repeats, pruned_bytes
    )
    result.timings["all_views"] = _measure(
        lambda: found.setdefault("all_views", search_views(state, prob, origins, context, prune_views=False)),
        repeats, pruned_bytes,
    )  # fmt: skip
    result.timings["fused"] = _measure(
        lambda: found.setdefault("fused", search_views(state, prob, origins, context, prune=False)), repeats,
        fused_bytes,
    )  # fmt: skip
    pruned, exhaustive, all_views = found["pruned"], found["fused"], found["all_views"]
    result.same_pruned_view = bool(pruned and exhaustive and all_views) and all(
        np.array_equal(pruned.cell, other.cell) and pruned.view_index == other.view_index
        for other in (exhaustive[0], all_views[0])
    )
    for kernel in ("two_step", "naive"):
        baseline_found: dict[str, tuple] = {}

        def baseline(kernel=kernel, found=baseline_found):
            found["best"] = baseline_view_search(state, prob, origins, context, kernel)

        timing = _measure(baseline, repeats)
        timing.peak_bytes += baseline_found["best"][2]  # the baseline's OpenCL buffers
        result.timings[kernel] = timing
        if kernel == "two_step":
            gain, index = baseline_found["best"][:2]
            best_cell = origins[index // n_views]
            result.same_best_view = (
                choice is not None and np.array_equal(best_cell, choice.cell) and index % n_views == choice.view_index
            )

    _time_original_variant(result, state, prob, origins, context, repeats, authors_origins)
    subset = origins[np.random.default_rng(0).permutation(origins.shape[0])[:numpy_origins]]
    numpy_context = PlanningContext(context.defaults, n_rays=case.n_rays, backend="numpy")
    numpy_timing = _measure(lambda: search_best_view(state, prob, subset, numpy_context), 1)
    numpy_timing.seconds *= origins.shape[0] / max(1, subset.shape[0])
    result.timings["numpy"] = numpy_timing
    return result


def _time_original_variant(result, state, prob, origins, context, repeats, authors_origins) -> None:
    """``pruned_original`` (our pruned search on the original variant, all origins) and ``authors``
    (the authors'-scheme baseline on a random subset of ``authors_origins`` origins, its time
    extrapolated linearly; one run: it is the slow one) into ``result``."""
    from nbv_prob_cnn.gain.variant import sample_count

    original = PlanningContext(context.defaults, n_rays=result.case.n_rays, backend="opencl",
                               origin_stride=result.case.stride, gain_variant="original")  # fmt: skip
    probability = "cnn" if result.case.method in ("cnn_prob", "cnn_prob_d") else "constant"
    free_hits = probability == "cnn"
    search = lambda chosen, prune: search_views(state, prob, chosen, original, probability=probability, prune=prune)  # noqa: E731
    search(origins, True)  # warm-up: the original variant's kernel build
    result.timings["pruned_original"] = _measure(lambda: search(origins, True), repeats)
    result.authors_samples = origins.shape[0] * result.rays * sample_count("original", context.active_sensor.r_max)
    subset = origins[np.sort(np.random.default_rng(1).permutation(origins.shape[0])[:authors_origins])]
    result.authors_origins = subset.shape[0]
    found: dict[str, tuple] = {}
    timing = _measure(lambda: found.setdefault("best", authors_view_search(state, prob, subset, original, free_hits)),
                      1)  # fmt: skip
    timing.seconds *= origins.shape[0] / max(1, subset.shape[0])
    timing.cpu_seconds *= origins.shape[0] / max(1, subset.shape[0])
    timing.peak_bytes += found["best"][2]
    result.timings["authors"] = timing
    ours = search(subset, False)
    n_views = original.membership.shape[1]
    index = found["best"][1]
    cell, view = subset[index // n_views : index // n_views + 1], index % n_views
    ours_there = origin_view_gains(
        state, prob, original.directions, original.active_sensor.r_max, original.membership, cell, "opencl",
        settings=GainSettings(variant="original", free_hits=free_hits),
    )  # fmt: skip
    result.same_authors_view = bool(ours) and (
        (np.array_equal(cell[0], ours[0].cell) and view == ours[0].view_index)
        or abs(float(ours_there[0, view]) - ours[0].gain) <= AUTHORS_TIE_MARGIN * ours[0].gain
    )


def _defaults(dataset: str):
    from nbv_prob_cnn.basics.camera import dataset_defaults

    return dataset_defaults(dataset)


def format_table(results: list[BenchResult]) -> str:
    """Markdown table: seconds per iteration, effective samples/s and peak memory per variant."""
    lines = [
        (
            "| case | unknown | origins | rays | iteration (s) | CNN (s) | pruned search (s) | "
            "pruned, all views (s) | fused search (s) | two-step (s) | naive (s) | numpy (s, extrap.) | "
            "iteration / pruned / all views / fused / two-step / naive CPU-s | pruned vs all views | pruned vs fused | "
            "fused vs two-step | fused vs naive | pruned samples/s | fused samples/s | naive samples/s | "
            "peak MB iteration / fused / two-step / naive | same best view | "
            "pruned original (s) | authors (s, extrap.) | authors vs pruned original | authors vs pruned | "
            "authors vs fused | authors vs naive | authors samples/s | authors: same view or tie (subset) |"
        ),
        "|" + "---|" * 30,
    ]
    for r in results:
        t = r.timings
        mb = " / ".join(f"{t[v].peak_bytes / 2**20:.0f}" for v in ("iteration", "fused", "two_step", "naive"))
        cpu = " / ".join(f"{t[v].cpu_seconds:.2f}" for v in VARIANTS[:6])
        lines.append(
            f"| {r.case.label} | {r.unknown_fraction:.2f} | {r.origins} | {r.rays} | {t['iteration'].seconds:.3f} | "
            f"{r.cnn_s:.3f} | {t['pruned'].seconds:.3f} | {t['all_views'].seconds:.3f} | {t['fused'].seconds:.3f} | "
            f"{t['two_step'].seconds:.3f} | {t['naive'].seconds:.3f} | {t['numpy'].seconds:.1f} | {cpu} | "
            f"{t['all_views'].seconds / t['pruned'].seconds:.1f}× | "
            f"{t['fused'].seconds / t['pruned'].seconds:.1f}× | "
            f"{t['two_step'].seconds / t['fused'].seconds:.1f}× | {t['naive'].seconds / t['fused'].seconds:.1f}× | "
            f"{r.samples_per_s('pruned'):.2e} | {r.samples_per_s('fused'):.2e} | "
            f"{r.samples_per_s('naive'):.2e} | {mb} | "
            f"{'yes' if r.same_best_view and r.same_pruned_view else 'NO'} | "
            f"{t['pruned_original'].seconds:.3f} | {t['authors'].seconds:.1f} ({r.authors_origins} origins) | "
            f"{t['authors'].seconds / t['pruned_original'].seconds:.0f}× | "
            f"{t['authors'].seconds / t['pruned'].seconds:.0f}× | {t['authors'].seconds / t['fused'].seconds:.0f}× | "
            f"{t['authors'].seconds / t['naive'].seconds:.1f}× | {r.samples_per_s('authors'):.2e} | "
            f"{'yes' if r.same_authors_view else 'NO'} |"
        )
    return "\n".join(lines)


SWEEP_VARIANTS = ("pruned", "all_views", "fused")


def planning_time_sweep(
    dataset: str, n_rays: int | None, views: int, seed: int = 1000, progress: bool = True, every: int = 1
):
    """Planning time against explored fraction (the analogue of the paper's Fig. 6): an
    exploration with ``prob_ig`` from a random first view; before every ``every``-th view the
    view search is timed side by side as ``pruned`` (the planners' search), ``all_views`` (the
    same without pruning views) and ``fused`` (exhaustive); the other views are planned by the
    pruned search alone. Returns rows of (view, explored fraction of all cells before planning,
    origins, then wall and CPU seconds per variant, same best view)."""
    from tqdm import tqdm

    from nbv_prob_cnn.basics.grid import unknown_fraction_all
    from nbv_prob_cnn.exploration.explore import first_view
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate(dataset, seed)
    context = PlanningContext(_defaults(dataset), rng=np.random.default_rng(seed), n_rays=n_rays, backend="opencl")
    state = np.full(world.shape, -1, dtype=np.int8)
    choice = first_view(world, context)
    rows = []
    for view in tqdm(range(views), desc=f"{dataset} sweep", unit="view", disable=not progress):
        if view > 0:
            prob = probability_with_constant(state, context.defaults.p0)
            origins = context.candidate_origins(state)
            options = {"pruned": (True, True), "all_views": (True, False), "fused": (False, False)}  # prune, views
            if (view - 1) % every:
                options = {"pruned": (True, True)}
            if view == 1:  # warm-up: kernel builds
                for prune, views_too in options.values():
                    search_views(state, prob, origins, context, prune=prune, prune_views=views_too)
            found, times = {}, []
            for name, (prune, views_too) in options.items():
                _fresh_grid()
                cpu, start = time.process_time(), time.perf_counter()
                found[name] = search_views(state, prob, origins, context, prune=prune, prune_views=views_too)
                times += [time.perf_counter() - start, time.process_time() - cpu]
            if not found["pruned"]:
                break
            choice = found["pruned"][0]
            if len(found) == len(SWEEP_VARIANTS):
                same = all(
                    found[n] and np.array_equal(found[n][0].cell, choice.cell)
                    and found[n][0].view_index == choice.view_index
                    for n in SWEEP_VARIANTS
                )  # fmt: skip
                rows.append((view, 1.0 - unknown_fraction_all(state), origins.shape[0], *times, same))
        observe(state, world.ground_truth, choice.cell, context.orientations[choice.view_index], context.active_sensor)
    return rows


def write_sweep(rows, label: str, out: Path, note: str = "") -> tuple[Path, Path]:
    """CSV and PNG (planning time per view against explored fraction) of a sweep; ``note`` goes
    under the title (e.g. the load average)."""
    from matplotlib.figure import Figure

    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"planning_time_{label}"
    header = ["view", "explored_fraction", "origins"]
    header += [f"{n}_{kind}" for n in SWEEP_VARIANTS for kind in ("wall_s", "cpu_s")] + ["same_best_view"]
    lines = [",".join(header)] + [
        ",".join([str(r[0]), f"{r[1]:.4f}", str(r[2]), *(f"{x:.4f}" for x in r[3:-1]), str(bool(r[-1]))]) for r in rows
    ]
    stem.with_suffix(".csv").write_text("\n".join(lines) + "\n")
    fig = Figure(figsize=(7, 4.5))
    ax = fig.add_subplot(1, 1, 1)
    explored = np.array([100 * r[1] for r in rows])
    for i, name in enumerate(SWEEP_VARIANTS):
        ax.plot(explored, [r[3 + 2 * i] for r in rows], "o-", color=f"C{i}", ms=3, label=f"{name} (wall)")
        ax.plot(explored, [r[4 + 2 * i] / 2 for r in rows], "x:", color=f"C{i}", ms=3, label=f"{name} (CPU-s / 2)")
    ax.set_xlabel("explored cells before planning (%)")
    ax.set_ylabel("view search time per iteration (s)")
    ax.set_title(f"{label}: view search time during an exploration" + (f"\n{note}" if note else ""), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(stem.with_suffix(".png"), dpi=90)
    return stem.with_suffix(".csv"), stem.with_suffix(".png")
