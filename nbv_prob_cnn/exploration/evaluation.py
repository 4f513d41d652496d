"""The method comparison of docs/method.md#exploration-protocol-and-metrics: every method on the same held-out
environments, one CSV
per run, then mean/spread curves (paper Fig. 5), time against explored fraction (Fig. 6) and
a table of the unknown fraction after given numbers of views.

Runs are Ray tasks (:func:`evaluate`): a local Ray instance by default, an existing cluster with
``address``, or plain in-process calls with ``workers=0`` (debugging). A task returns its log;
the driver writes ``runs/<dataset>_<method>_seed<seed>.csv`` (plus a small ``.json`` with the
views asked for, why the run stopped and the fingerprint of the weights the method read), so
workers need no shared file system. Runs are resumable: a run whose files exist (for at least as
many views) is read back, not recomputed, unless the method's weights file has changed since
(its fingerprint differs from the one recorded, or none was recorded): then the run is redone
and the progress output says so. Methods without weights record none and are never redone.
Worlds and weights are read on the worker (``NBV_CACHE_DIR`` and ``NBV_WEIGHTS_DIR`` are passed
on); every node of a cluster needs this package installed (``launch_scripts/setup.sh``).

With ``chamfer`` each run also measures the Chamfer distance of its TSDF mesh after the last view
(:mod:`~nbv_prob_cnn.exploration.mesh_chamfer`, stored in its ``.json``; a stored run without one is
redone). With ``replay`` runs are not planned but replayed from the stored runs of another folder
(:mod:`~nbv_prob_cnn.exploration.replay`: the same views, the surface coverage and the Chamfer
distance measured anew).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from nbv_prob_cnn.basics.datasets import EVALUATION_SEEDS, dataset_spec
from nbv_prob_cnn.exploration.explore import explore, write_csv
from nbv_prob_cnn.exploration.mesh_chamfer import CHAMFER_KEY
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.planners import PlanningContext, make_planner, method_spec

#: Evaluation environments of a quick comparison: the first ten of the protocol's (test split).
DEFAULT_SEEDS = EVALUATION_SEEDS[:10]
#: Environment variables passed on to Ray workers (caches, weights, the OpenCL device choice and
#: the ICD loader's vendor folder, so workers ray-cast on the same device as the driver).
FORWARDED_ENV = ("NBV_CACHE_DIR", "NBV_WEIGHTS_DIR", "NBV_OPENCL_DEVICE", "OCL_ICD_VENDORS")
#: Key of a run's ``.json`` that holds :func:`weights_fingerprint` of the weights it ran with.
WEIGHTS_KEY = "weights_sha256"
#: Key of a run's ``.json`` that holds its gain variant (written only when not ``"paper"``).
VARIANT_KEY = "gain_variant"
#: Key of a run's ``.json`` that holds the view guard's threshold in cells (written only for a
#: guarded run, :mod:`~nbv_prob_cnn.exploration.view_guard`; absent: the paper's plain loop).
GUARD_KEY = "guard_min_cells"
#: Key of a run's ``.json`` that holds a surface method's blend (docs/method.md#surface-gain; written
#: only for the surface methods: a run of another blend is redone).
SURFACE_KEY = "surface_blend"
#: A surface method's run records how many views it re-ranked by their image rays (none recorded: 0,
#: the runs made before the re-ranking).
RERANK_KEY = "image_rerank"
#: File-name label of guarded runs and their summaries (they sit beside the plain ones).
GUARDED = "guarded"


@dataclass
class RunLog:
    """Per-view columns of one run, as read from its CSV, and what its ``.json`` measured.

    ``surface_coverage`` is None for a run CSV written before that column; ``chamfer`` (the
    :class:`~nbv_prob_cnn.exploration.mesh_chamfer.ChamferResult` fields) None for a run without
    one; ``seed`` None when the file name gives none."""

    unknown_fraction: np.ndarray
    unknown_fraction_all: np.ndarray
    time_total_s: np.ndarray
    surface_coverage: np.ndarray | None = None
    chamfer: dict | None = None
    seed: int | None = None


def read_run(path: Path, views: int | None = None) -> RunLog:
    """The log of a run CSV (its first ``views`` rows when given), with the Chamfer distance of
    its ``.json`` when there is one."""
    with open(path) as handle:
        reader = csv.DictReader(handle)
        rows = list(reader)[:views]
        header = reader.fieldnames or []
    column = lambda name: np.array([float(r[name]) for r in rows])  # noqa: E731
    meta_path = Path(path).with_suffix(".json")
    chamfer = None
    if meta_path.is_file():
        try:
            chamfer = json.loads(meta_path.read_text()).get(CHAMFER_KEY)
        except (ValueError, AttributeError):
            chamfer = None
    seed = re.search(r"_seed(\d+)\.csv$", Path(path).name)
    return RunLog(
        column("unknown_fraction"), column("unknown_fraction_all"), column("time_total_s"),
        column("surface_coverage") if "surface_coverage" in header else None,
        chamfer, int(seed.group(1)) if seed else None,
    )  # fmt: skip


def run_path(out: Path, dataset: str, method: str, seed: int, guarded: bool = False) -> Path:
    """``runs/<dataset>_<method>[_guarded]_seed<seed>.csv`` under ``out``."""
    label = f"_{GUARDED}" if guarded else ""
    return out / "runs" / f"{dataset}_{method}{label}_seed{seed}.csv"


def weights_fingerprint(dataset: str, method: str) -> str | None:
    """First 16 hex digits of the sha256 of the weights file ``method`` reads on ``dataset``
    (None: a method without weights)."""
    from nbv_prob_cnn.completion.inference import default_weights_path

    weights = method_spec(method).weights
    if weights is None:
        return None
    return hashlib.sha256(default_weights_path(dataset, weights).read_bytes()).hexdigest()[:16]


def run_status(
    path: Path,
    views: int,
    weights: str | None = None,
    gain_variant: str = "paper",
    guard_min_cells: int | None = None,
    chamfer: bool = False,
    surface_blend: float | None = None,
    image_rerank: int | None = None,
) -> str:
    """``"done"``: the run CSV exists for at least ``views`` views (or stopped early in a run that
    asked for as many) and was made with the weights of fingerprint ``weights`` (None: a method
    without weights); ``"missing"``, ``"short"``, ``"other weights"`` (a run of a method with
    weights whose ``.json`` records another fingerprint or none), or ``"other gain variant"`` (its
    ``.json`` records another ``gain_variant``; none recorded: ``"paper"``), or ``"other guard"``
    (another view-guard threshold, ``guard_min_cells``; None: the plain loop, none recorded), or,
    with ``chamfer``, ``"no chamfer"`` (its ``.json`` holds no Chamfer distance), or ``"other surface
    blend"`` (a surface method's run whose ``.json`` records another blend than ``surface_blend``), or
    ``"other image re-ranking"`` (another ``image_rerank``, :data:`RERANK_KEY`; None: a method that
    does not re-rank)."""
    if not path.is_file():
        return "missing"
    meta_path = path.with_suffix(".json")
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text())
            enough = int(meta["views"]) >= views
        except (ValueError, KeyError, TypeError):
            return "short"
        recorded = meta.get(WEIGHTS_KEY)
        if meta.get(VARIANT_KEY, "paper") != gain_variant:
            return "other gain variant"
        if meta.get(GUARD_KEY) != guard_min_cells:
            return "other guard"
        if chamfer and CHAMFER_KEY not in meta:
            return "no chamfer"
        if meta.get(SURFACE_KEY) != surface_blend:
            return "other surface blend"
        if meta.get(RERANK_KEY, None if surface_blend is None else 0) != image_rerank:
            return "other image re-ranking"
    else:
        if gain_variant != "paper":
            return "other gain variant"
        if guard_min_cells is not None:
            return "other guard"
        if chamfer:
            return "no chamfer"
        if surface_blend is not None:
            return "other surface blend"
        if image_rerank is not None:
            return "other image re-ranking"
        with open(path) as handle:
            enough = sum(1 for _ in handle) - 1 >= views
        recorded = None
    if not enough:
        return "short"
    return "done" if recorded == weights else "other weights"


def run_one(
    dataset: str,
    method: str,
    seed: int,
    views: int,
    backend: str = "auto",
    gain_variant: str = "paper",
    guard_min_cells: int | None = None,
    chamfer: bool = False,
    replay_from: str | None = None,
) -> tuple[str, dict]:
    """One run of docs/method.md#exploration-protocol-and-metrics (the body of a Ray task): the CSV text and
    its metadata.
    ``guard_min_cells``: run with the view guard of this threshold (None: the plain loop).
    ``chamfer``: measure the Chamfer distance of the run's TSDF mesh after its last view.
    ``replay_from``: replay that stored run CSV instead of planning
    (:func:`~nbv_prob_cnn.exploration.replay.replay_run`)."""
    if replay_from is not None:
        from nbv_prob_cnn.exploration.replay import replay_run

        return replay_run(dataset, seed, views, replay_from, gain_variant, chamfer)
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate(dataset, seed)
    weights = weights_fingerprint(dataset, method)  # of the file this worker reads
    # same first view for every method: the rng is seeded by the environment only
    context = PlanningContext(
        dataset_spec(dataset),
        rng=np.random.default_rng(seed),
        ground_truth=world.ground_truth,
        backend=backend,
        gain_variant=gain_variant,
    )
    guard = None if guard_min_cells is None else ViewGuard(guard_min_cells)
    result = explore(world, make_planner(method), context, views, progress=False, guard=guard, chamfer=chamfer)
    text = io.StringIO()
    write_csv(result.records, text)
    meta = {"views": views, "stop_reason": result.stop_reason, "host": os.uname().nodename, WEIGHTS_KEY: weights}
    if gain_variant != "paper":
        meta[VARIANT_KEY] = gain_variant
    if guard_min_cells is not None:
        meta[GUARD_KEY] = guard_min_cells
    if result.chamfer is not None:
        meta[CHAMFER_KEY] = result.chamfer.as_dict()
    if _surface_blend(method) is not None:
        meta[SURFACE_KEY] = context.surface_blend
        meta[RERANK_KEY] = context.image_rerank
    return text.getvalue(), meta


def _image_rerank(method: str) -> int | None:
    """The views a surface method re-ranks by their image rays (the default), None for the other methods."""
    from nbv_prob_cnn.planners.base import DEFAULT_IMAGE_RERANK

    return DEFAULT_IMAGE_RERANK if _surface_blend(method) is not None else None


def _surface_blend(method: str) -> float | None:
    """The blend a surface method runs with (the default), None for the other methods."""
    from nbv_prob_cnn.gain.settings import DEFAULT_SURFACE_BLEND
    from nbv_prob_cnn.planners.methods import GAIN_METHODS

    gain = GAIN_METHODS.get(method)
    return DEFAULT_SURFACE_BLEND if gain is not None and gain.surface else None


def _store(path: Path, text: str, meta: dict) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    path.with_suffix(".json").write_text(json.dumps(meta) + "\n")
    tmp.replace(path)


def check_weights(dataset: str, methods: list[str]) -> None:
    """Fail before any run when a method's trained weights are missing (names the command)."""
    from nbv_prob_cnn.completion.inference import default_weights_path, read_weights

    for method in methods:
        weights = method_spec(method).weights
        if weights is not None:
            read_weights(default_weights_path(dataset, weights), dataset, weights)


def evaluate(
    dataset: str,
    methods: list[str],
    seeds: list[int],
    views: int,
    out: Path,
    progress: bool = True,
    workers: int | None = None,
    address: str | None = None,
    backend: str = "auto",
    gain_variant: str = "paper",
    guard: bool = False,
    guard_min_cells: int | None = None,
    chamfer: bool = False,
    replay: Path | None = None,
) -> dict[str, list[RunLog]]:
    """Run (or read back) every method on every seed; returns the logs per method.

    Args:
        workers: 0 = in this process, one run after the other (debugging); None = a local Ray
            instance with one task per CPU; N = a local Ray instance with N CPUs. Ignored with
            ``address``.
        address: an existing Ray cluster (``ray start --head`` prints it), e.g. ``"10.0.0.5:6379"``.
        backend: ray-casting backend of the runs.
        gain_variant: gain variant of the runs (:mod:`nbv_prob_cnn.gain.variant`); a stored run
            of another variant is redone.
        guard: every run with the view guard (:mod:`~nbv_prob_cnn.exploration.view_guard`), stored
            as ``<dataset>_<method>_guarded_seed<seed>.csv`` beside the plain runs; False: the
            paper's plain loop.
        guard_min_cells: the guard's threshold (default: 5e-5 of the data set's grid cells).
        chamfer: every run also measures the Chamfer distance of its TSDF mesh after its last
            view (3D data sets); a stored run without one is redone.
        replay: a folder of stored runs (``runs/`` under it, as ``out``'s): each run not done in
            ``out`` is replayed from its namesake there, which must hold at least ``views`` views
            of the same gain variant and guard (the weights it ran with are kept with it); a run of
            ``out`` whose namesake is missing there (a method planned into ``out`` first) is read
            back as it is, so one table holds both.

    Raises:
        ValueError: ``chamfer`` on 2D, or a run ``replay`` lacks or cannot replay.
    """
    for method in methods:
        method_spec(method)  # fail early on an unknown name
    if chamfer and dataset_spec(dataset).dims != 3:
        raise ValueError(f"chamfer: needs a 3D data set with meshes (3dt, 3du), not {dataset}")
    threshold = None
    if guard:
        threshold = ViewGuard.for_grid(dataset_spec(dataset).shape, guard_min_cells).min_changed_cells
    if replay is None:
        check_weights(dataset, methods)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    jobs = [(seed, method) for seed in seeds for method in methods]
    sources: dict[tuple[int, str], str | None] = dict.fromkeys(jobs)
    if replay is None:
        current = {method: weights_fingerprint(dataset, method) for method in methods}
        fingerprints = {(seed, method): current[method] for seed, method in jobs}
    else:  # a replayed run keeps the weights its source ran with
        fingerprints = {}
        for seed, method in jobs:
            source = run_path(replay, dataset, method, seed, guard)
            made = run_path(out, dataset, method, seed, guard)
            if not source.is_file() and made.is_file():  # planned in out (a method the source lacks): read back
                fingerprints[seed, method] = recorded_weights(made)
                continue
            fingerprints[seed, method] = recorded_weights(source)
            status = run_status(
                source, views, fingerprints[seed, method], gain_variant, threshold,
                surface_blend=_surface_blend(method), image_rerank=_image_rerank(method),
            )  # fmt: skip
            if status != "done":
                raise ValueError(f"replay: {source}: {status} (needs {views} views of this gain variant and guard)")
            sources[seed, method] = str(source)
    pending: dict[tuple[int, str], tuple] = {}  # (seed, method) -> the arguments of run_one
    redo: dict[str, tuple[int, str | None]] = {}  # method -> runs made with other weights, the weights now
    for seed, method in jobs:
        status = run_status(
            run_path(out, dataset, method, seed, guard), views, fingerprints[seed, method], gain_variant, threshold,
            chamfer, _surface_blend(method), _image_rerank(method),
        )  # fmt: skip
        if status != "done":
            pending[seed, method] = (dataset, method, seed, views, backend, gain_variant, threshold, chamfer,
                                     sources[seed, method])  # fmt: skip
        if status == "other weights":
            redo[method] = (redo.get(method, (0, None))[0] + 1, fingerprints[seed, method])
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(pending), desc=f"evaluate {dataset}", unit="run",
               disable=not progress)  # fmt: skip
    for method, (count, weights) in redo.items():
        if progress:
            bar.write(f"{dataset} {method}: redoing {count} run(s) made with other weights than the current "
                      f"ones (sha256 {weights})", file=sys.stderr)  # fmt: skip
    if pending and workers == 0 and address is None:
        for (seed, method), arguments in pending.items():
            _store(run_path(out, dataset, method, seed, guard), *run_one(*arguments))
            bar.update(1)
            bar.set_postfix(seed=seed, method=method)
    elif pending:
        _run_on_ray(pending, out, guard, workers, address, bar)
    bar.close()
    logs: dict[str, list[RunLog]] = {m: [] for m in methods}
    for seed, method in jobs:
        logs[method].append(read_run(run_path(out, dataset, method, seed, guard), views))
    return logs


def recorded_weights(path: Path) -> str | None:
    """The weights fingerprint a stored run's ``.json`` records (None: none, or no ``.json``)."""
    try:
        return json.loads(path.with_suffix(".json").read_text()).get(WEIGHTS_KEY)
    except (OSError, ValueError, AttributeError):
        return None


def _run_on_ray(
    pending: dict[tuple[int, str], tuple], out: Path, guard: bool, workers: int | None, address: str | None, bar
) -> None:
    """:func:`run_one` of each ``pending`` job's arguments as a Ray task; each run stored as it ends."""
    import ray

    env = {k: os.environ[k] for k in FORWARDED_ENV if k in os.environ}
    options: dict[str, Any] = {"runtime_env": {"env_vars": env}, "include_dashboard": False, "log_to_driver": False}
    if address is None:
        options["num_cpus"] = workers or os.cpu_count()
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address, **options)
    try:
        task = ray.remote(num_cpus=1, max_retries=1)(run_one)
        futures = {task.remote(*arguments): job for job, arguments in pending.items()}
        remaining = list(futures)
        while remaining:
            done, remaining = ray.wait(remaining, num_returns=1)
            seed, method = futures[done[0]]
            path = run_path(out, pending[seed, method][0], method, seed, guard)
            _store(path, *ray.get(done[0]))  # written as soon as it finishes
            bar.update(1)
            bar.set_postfix(seed=seed, method=method)
    finally:
        if started_here:
            ray.shutdown()


def padded(values: list[np.ndarray], length: int) -> np.ndarray:
    """Stack per-view curves; a run that stopped early keeps its last value."""
    return np.array(
        [np.concatenate([v, np.full(length - len(v), v[-1])]) if len(v) < length else v[:length] for v in values]
    )


def paired_difference(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per view, the mean of ``a − b`` over paired runs ``(runs, views)`` (same environment, same
    first view) and its standard error (NaN with a single pair)."""
    diff = a - b
    if diff.shape[0] < 2:
        return diff.mean(axis=0), np.full(diff.shape[1], np.nan)
    return diff.mean(axis=0), diff.std(axis=0, ddof=1) / np.sqrt(diff.shape[0])


def summary_table(logs: dict[str, list[RunLog]], at_views: list[int]) -> str:
    """Markdown: mean ± std of the unknown fraction after each of ``at_views`` views."""
    header = "| method | runs | " + " | ".join(f"after {v} views" for v in at_views) + " | mean planning time (s) |"
    lines = [header, "|---|---|" + "---|" * len(at_views) + "---|"]
    for method, runs in logs.items():
        curves = padded([r.unknown_fraction for r in runs], max(at_views))
        cells = [f"{curves[:, v - 1].mean():.4f} ± {curves[:, v - 1].std():.4f}" for v in at_views]
        times = np.concatenate([r.time_total_s[1:] for r in runs])
        lines.append(f"| {method} | {len(runs)} | " + " | ".join(cells) + f" | {times.mean():.3f} |")
    return "\n".join(lines)


def save_plots(
    logs: dict[str, list[RunLog]], views: int, dataset: str, out: Path, stem: str | None = None
) -> list[Path]:
    """Unknown fraction per view (mean ± std) and planning time against explored fraction, as
    ``<stem>_comparison.png`` (default stem: the data set)."""
    fig = Figure(figsize=(13, 5))
    ax_curve, ax_time = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for method, runs in logs.items():
        curves = padded([r.unknown_fraction for r in runs], views) * 100
        x = np.arange(1, views + 1)
        ax_curve.plot(x, curves.mean(axis=0), label=method)
        low = np.clip(curves.mean(axis=0) - curves.std(axis=0), 0, 100)
        high = np.clip(curves.mean(axis=0) + curves.std(axis=0), 0, 100)
        ax_curve.fill_between(x, low, high, alpha=0.15)
        explored = np.concatenate([100 * (1 - r.unknown_fraction_all[:-1]) for r in runs])
        times = np.concatenate([r.time_total_s[1:] for r in runs])
        ax_time.plot(explored, times, ".", ms=3, label=method)
    ax_curve.set_xlabel("views")
    ax_curve.set_ylabel("unknown empty cells (%)")
    label = "" if stem in (None, dataset) else ", " + str(stem).removeprefix(f"{dataset}_").replace("_", " ")
    ax_curve.set_title(f"{dataset.upper()}{label}: unknown fraction (mean ± std over environments)")
    ax_curve.grid(alpha=0.3)
    ax_curve.legend()
    ax_time.set_xlabel("explored cells before planning (%)")
    ax_time.set_ylabel("planning time per view (s)")
    ax_time.set_title("computation time per iteration")
    ax_time.grid(alpha=0.3)
    ax_time.legend()
    fig.tight_layout()
    path = out / f"{stem or dataset}_comparison.png"
    fig.savefig(path, dpi=90)
    return [path]


def write_summary_csv(logs: dict[str, list[RunLog]], views: int, path: Path) -> None:
    """Per view and method: mean and std of the unknown fraction, then of the surface coverage
    (``n/a`` for a method with a run CSV written before that column)."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["method", "view", "runs", "mean_unknown_fraction", "std_unknown_fraction",
                         "mean_surface_coverage", "std_surface_coverage"])  # fmt: skip
        for method, runs in logs.items():
            curves = padded([r.unknown_fraction for r in runs], views)
            coverage = coverage_curves(runs, views)
            for v in range(views):
                seen = (
                    ["n/a", "n/a"]
                    if coverage is None
                    else [f"{coverage[:, v].mean():.6f}", f"{coverage[:, v].std():.6f}"]
                )
                writer.writerow(
                    [method, v + 1, len(runs), f"{curves[:, v].mean():.6f}", f"{curves[:, v].std():.6f}", *seen]
                )


def coverage_curves(runs: list[RunLog], views: int) -> np.ndarray | None:
    """The surface coverage per run and view ``(runs, views)`` (:func:`padded`); None when a run
    CSV predates the column."""
    if any(r.surface_coverage is None for r in runs):
        return None
    return padded([r.surface_coverage for r in runs if r.surface_coverage is not None], views)
