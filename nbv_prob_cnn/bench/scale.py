"""``nbv bench --suite scale``: one ``cnn_prob`` planning step against the size of the grid and of the
workspace (docs/performance.md#scale), today's path beside the local one, in one run.

Grids: tabletop-like, 3DT worlds side by side (world ``seed``, ``seed + 1``, ... in x-major order, cut
to the size), free space above the 96 cells of a 3DT world; each half explored by random views as in
``nbv bench --suite planning`` (:func:`~nbv_prob_cnn.bench.planning.half_explored`). Sizes: 128×128×96
(3DT itself), 192×192×96, 256×256×96, 256×256×192. Every empty cell is a candidate (origin stride 1),
the 3DT sensor (range 128 cells), N_rays = 4.

Paths, each row in a fresh child process (its peak RSS is that process's ``VmHWM``: Python, torch and
the OpenCL runtime included, about 0.3 GB before any grid); the child first plans on a 48³ corner of
the grid (weights, kernels) and then times one step:

* ``today``: the planner before issue #35: the completion CNN over the whole grid
  (:func:`~nbv_prob_cnn.completion.inference.complete`), every empty cell, the coarse-to-fine search
  (:func:`~nbv_prob_cnn.gain.best_origin_view`) on blocks of :data:`TODAY_BLOCK` cells (both paths run
  the CNN's current, leaner forward pass);
* ``local``: the planner (``make_planner("cnn_prob")``): the origins within the rays' reach of unknown
  space, the CNN by tiles over their reach (:mod:`nbv_prob_cnn.planners.local_completion`), the search
  on that reach;
* ``window`` (workspace rows): ``local`` with the CNN on the workspace grown by
  :data:`WINDOW_MARGIN` cells only (``p0`` outside);
* ``local_bf16`` (size rows) and ``window_bf16`` (the kitchen's workspace): the same with the CNN in
  bfloat16 (opt-in, ``cnn_precision``), where the CPU has bfloat16 convolutions.

Workspace rows: the 256×256×192 grid with a centred box of camera positions 0.5, 1.0 and 1.5 m wide
standing on the table, ``local`` and ``window`` (today's path there is the size row's whole-grid CNN
and a search over fewer origins). The kitchen rows: :mod:`nbv_prob_cnn.bench.scale_kitchen`.
"""

from __future__ import annotations

import csv
import multiprocessing
import os
import tempfile
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.peak_memory import peak_rss_mb

#: Grid shapes of the size rows (the first is 3DT's own).
SIZES: tuple[tuple[int, int, int], ...] = ((128, 128, 96), (192, 192, 96), (256, 256, 96), (256, 256, 192))
#: Workspace box widths (m) of the workspace rows, on the largest grid.
WORKSPACES_M = (0.5, 1.0, 1.5)
#: Margin (cells) of the ``window`` path's CNN window around the workspace.
WINDOW_MARGIN = 48
#: Row groups of the suite: the tabletop-like grids (sizes and workspaces) and the real kitchen.
GROUPS = ("grids", "kitchen")
#: Corner of the grid the child plans on first (weights, kernels).
WARM_UP_CELLS = 48
#: Colour of each path in the plot.
PATH_COLOURS = {
    "today": "tab:blue", "local": "tab:orange", "window": "tab:green", "local_bf16": "tab:red",
    "window_bf16": "tab:purple",
}  # fmt: skip
#: Suffix of a path whose CNN runs in bfloat16 (``PlanningContext.cnn_precision``).
BF16_SUFFIX = "_bf16"
#: Bounded block (cells per axis) of the search before issue #35 (two origin strides).
TODAY_BLOCK = 2
#: Seconds a child may take.
CHILD_TIMEOUT_S = 900


@dataclass
class ScaleRow:
    """One measured step. ``seconds``: the whole step; ``cnn_s`` the completion; ``search_s`` the rest
    (origins and view search); ``peak_rss_mb``: the child process's ``VmHWM``."""

    grid: str
    cells: int
    path: str
    workspace_m: float
    candidates: int
    seconds: float
    cnn_s: float
    search_s: float
    peak_rss_mb: float
    cell: str
    view: int
    gain: float


def scale_truth(shape: tuple[int, int, int], seed: int) -> np.ndarray:
    """Ground truth of a tabletop-like grid of ``shape``: 3DT worlds ``seed, seed + 1, ...`` side by side
    in x-major order (cut to the shape), free space above their 96 cells."""
    from nbv_prob_cnn.worlds import load_or_generate

    if len(shape) != 3 or min(shape) < 1:
        raise ValueError(f"shape: expected three positive sizes, got {shape}")
    truth = np.zeros(shape, dtype=np.uint8)
    k = 0
    for x in range(0, shape[0], 128):
        for y in range(0, shape[1], 128):
            world = load_or_generate("3dt", seed + k).ground_truth
            k += 1
            block = world[: shape[0] - x, : shape[1] - y, : shape[2]]
            truth[x : x + block.shape[0], y : y + block.shape[1], : block.shape[2]] = block
    return truth


def scale_state(shape: tuple[int, int, int], seed: int) -> np.ndarray:
    """A half-explored state of :func:`scale_truth` (random views until half the free cells are seen)."""
    from nbv_prob_cnn.bench.planning import half_explored
    from nbv_prob_cnn.planners import PlanningContext
    from nbv_prob_cnn.worlds.world import World

    truth = scale_truth(shape, seed)
    context = PlanningContext.for_dataset("3dt", rng=np.random.default_rng(seed), backend="opencl")
    world = World("3dt", seed, 0, truth, context.defaults.resolution_m, np.zeros(3))
    return half_explored(world, context)


def workspace_box(shape: tuple[int, ...], width_m: float, resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Cells ``[lo, hi)`` of a box ``width_m`` wide, centred in x and y, from the table top (z 8) up."""
    side = int(round(width_m / resolution_m))
    centre = np.array(shape[:2]) // 2
    lo = np.array([*(centre - side // 2), 8])
    hi = np.minimum(lo + side, shape)
    return lo, hi


def _step(path: str, state: np.ndarray, box: tuple[np.ndarray, np.ndarray] | None) -> dict:
    """One planning step on ``path``: best view, candidates and stage times."""
    from nbv_prob_cnn.completion import complete
    from nbv_prob_cnn.gain import best_origin_view
    from nbv_prob_cnn.planners import PlanningContext, make_planner
    from nbv_prob_cnn.planners.base import BoundedFilter, ViewChoice

    def inside(origins: np.ndarray) -> np.ndarray:
        return origins if box is None else origins[np.all((origins >= box[0]) & (origins < box[1]), axis=1)]

    in_box = None if box is None else BoundedFilter((tuple(box[0]), tuple(box[1])), inside)

    base, precision = path.removesuffix(BF16_SUFFIX), "bfloat16" if path.endswith(BF16_SUFFIX) else "float32"
    context = PlanningContext.for_dataset(
        "3dt", backend="opencl", origin_stride=1, cnn_window=WINDOW_MARGIN if base == "window" else None,
        cnn_precision=precision,
    )  # fmt: skip
    start = time.perf_counter()
    if path == "today":
        prob = complete(state, dataset="3dt")
        cnn_s = time.perf_counter() - start
        origins = inside(context.candidate_origins(state))
        index, view, gain = best_origin_view(
            state, prob, context.directions, context.active_sensor.r_max, context.membership, origins, "opencl",
            settings=context.gain_settings("prob", "cnn"), block_size=TODAY_BLOCK,
        )  # fmt: skip
        found = [ViewChoice(origins[index], int(view), float(gain))] if gain > 0.0 else []
        candidates = origins.shape[0]
    else:
        found = make_planner("cnn_prob").rank(state, context, 1, in_box)
        cnn_s = found[0].times["cnn"] if found else float("nan")
        candidates = -1  # counted after the peak RSS is read (the planner does not report them)
    seconds = time.perf_counter() - start
    best = found[0] if found else None
    return {
        "seconds": seconds, "cnn_s": cnn_s, "search_s": seconds - cnn_s, "candidates": candidates,
        "cell": "" if best is None else " ".join(str(int(v)) for v in best.cell),
        "view": -1 if best is None else best.view_index, "gain": 0.0 if best is None else best.gain,
    }  # fmt: skip


def _local_candidates(state: np.ndarray, box: tuple[np.ndarray, np.ndarray] | None) -> int:
    """The origins the planner searches: empty cells (in the box) within the rays' reach of unknown space."""
    from nbv_prob_cnn.gain import empty_origins
    from nbv_prob_cnn.planners.candidates import near_unknown_origins, ray_reach

    origins = empty_origins(state)
    if box is not None:
        origins = origins[np.all((origins >= box[0]) & (origins < box[1]), axis=1)]
    return int(near_unknown_origins(state, origins, ray_reach(128)).shape[0])


def _child(path: str, state_file: str, box: tuple[np.ndarray, np.ndarray] | None, queue) -> None:
    """Child process: warm up on a corner, time one step, report it with the peak RSS."""
    try:
        state = np.load(state_file)
        corner = np.ascontiguousarray(state[:WARM_UP_CELLS, :WARM_UP_CELLS, :WARM_UP_CELLS])
        _step(path, corner, None)
        result = _step(path, state, box)
        result["peak_rss_mb"] = peak_rss_mb()
        if result["candidates"] < 0:
            result["candidates"] = _local_candidates(state, box)
        queue.put(result)
    except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises it
        queue.put({"error": f"{type(exc).__name__}: {exc}"})


def _result(child, queue) -> dict:
    """The child's report; an error when it ends without one or runs past :data:`CHILD_TIMEOUT_S`."""
    import queue as queues

    deadline = time.monotonic() + CHILD_TIMEOUT_S
    while time.monotonic() < deadline:
        try:
            return queue.get(timeout=1.0)
        except queues.Empty:
            if not child.is_alive():
                return {"error": f"the child process ended with exit code {child.exitcode} and no result"}
    return {"error": f"no result within {CHILD_TIMEOUT_S} s"}


def measure(path: str, state: np.ndarray, box: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Run :func:`_step` for ``path`` on ``state`` in a fresh (spawned) process; its result and peak RSS.

    Raises:
        RuntimeError: the child failed or timed out.
    """
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    with tempfile.TemporaryDirectory(prefix="nbv_scale_") as folder:
        state_file = os.path.join(folder, "state.npy")
        np.save(state_file, state)
        child = context.Process(target=_child, args=(path, state_file, box, queue))
        child.start()
        try:
            result = _result(child, queue)
        finally:
            child.join(timeout=60)
            if child.is_alive():
                child.terminate()
    if "error" in result:
        raise RuntimeError(f"scale bench, path {path}: {result['error']}")
    return result


def scale_benchmark(
    seed: int = 1000, out_dir: str | Path = "docs", sizes=SIZES, workspaces=WORKSPACES_M, groups=GROUPS
) -> str:
    """Every row of ``groups`` (``grids``: the size and workspace rows; ``kitchen``: the recording's rows) in
    one run, each printed as it is measured: CSV and PNG in ``out_dir`` (``scale.csv``, ``scale.png``; the
    kitchen alone: ``scale_kitchen.csv``); returns the closing report (ratios, targets, files)."""
    from nbv_prob_cnn.basics.camera import dataset_defaults
    from nbv_prob_cnn.bench.scale_kitchen import KITCHEN, kitchen_steps, kitchen_targets
    from nbv_prob_cnn.completion.inference import cpu_has_bfloat16

    unknown = set(groups) - set(GROUPS)
    if unknown or not groups:
        raise ValueError(f"groups: expected some of {GROUPS}, got {list(groups)}")
    resolution = dataset_defaults("3dt").resolution_m
    rows: list[ScaleRow] = []
    report: list[str] = []
    bf16 = cpu_has_bfloat16()  # the _bf16 rows are measured only then
    if not bf16:
        report.append("bfloat16 rows: skipped, this CPU has no bfloat16 convolutions (AVX512 or AMX)")
    if "grids" in groups:
        states = {}
        for shape in sizes:
            state = scale_state(shape, seed)
            states[shape] = state
            label = "×".join(str(s) for s in shape)
            for path in ("today", "local", *(("local" + BF16_SUFFIX,) if bf16 else ())):
                result = measure(path, state)
                rows.append(ScaleRow(label, int(np.prod(shape)), path, 0.0, **_fields(result)))
                print(_line(rows[-1]), flush=True)
        largest = max(sizes, key=lambda s: int(np.prod(s)))
        for width in workspaces:
            box = workspace_box(largest, width, resolution)
            label = "×".join(str(s) for s in largest)
            for path in ("local", "window"):
                result = measure(path, states[largest], box)
                rows.append(ScaleRow(label, int(np.prod(largest)), path, width, **_fields(result)))
                print(_line(rows[-1]), flush=True)
        report += ratio_lines(rows, sizes)
    if "kitchen" in groups:
        if KITCHEN.is_dir():
            paths = ("local", "window", *(("window" + BF16_SUFFIX,) if bf16 else ()))
            for step in kitchen_steps(measure, workspace_paths=paths):
                rows.append(ScaleRow(step.grid, step.cells, step.path, step.workspace_m, **_fields(step.result)))
                print(_line(rows[-1]), flush=True)
            report.append(kitchen_targets(rows))
        else:
            report.append(f"kitchen: skipped, {KITCHEN} is absent")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    files = []
    if "grids" in groups:
        files.append(write_scale_csv(rows, out / "scale.csv"))
        files.append(plot_scale(rows, out / "scale.png", note=f"load average at the end {load}"))
    elif rows:
        files.append(write_scale_csv(rows, out / "scale_kitchen.csv"))
    return "\n".join(["", *report, f"load average at the end: {load}", f"wrote {', '.join(map(str, files))}"])


def _fields(result: dict) -> dict:
    keep = {f.name for f in fields(ScaleRow)} - {"grid", "cells", "path", "workspace_m"}
    return {k: result[k] for k in keep}


def _line(row: ScaleRow) -> str:
    where = f", workspace {row.workspace_m:.1f} m" if row.workspace_m else ""
    return (
        f"{row.grid}{where} {row.path}: {row.seconds:.2f} s (CNN {row.cnn_s:.2f} s, search {row.search_s:.2f} s), "
        f"peak RSS {row.peak_rss_mb:.0f} MB, best view {row.cell} #{row.view} gain {row.gain:.4f}"
    )


def ratio_lines(rows: list[ScaleRow], sizes=SIZES) -> list[str]:
    """Ratios of the report: local against today per grid, the largest grid against 3DT per path, and
    the targets of issue #35."""
    by = {(r.grid, r.path, r.workspace_m): r for r in rows}
    labels = ["×".join(str(s) for s in shape) for shape in sizes]
    out = []
    for label in labels:
        today, local = by[(label, "today", 0.0)], by[(label, "local", 0.0)]
        same = today.cell == local.cell and today.view == local.view
        out.append(
            f"{label}: local / today time {local.seconds / today.seconds:.2f}, peak RSS "
            f"{local.peak_rss_mb / today.peak_rss_mb:.2f}; same best view: {'yes' if same else 'NO'}"
        )
    first, last = labels[0], labels[-1]
    paths = [p for p in ("today", "local", "local" + BF16_SUFFIX) if (last, p, 0.0) in by and (first, p, 0.0) in by]
    for path in paths:
        big, small = by[(last, path, 0.0)], by[(first, path, 0.0)]
        out.append(
            f"{path}: {last} / {first} time {big.seconds / small.seconds:.1f}× "
            f"for {big.cells / small.cells:.0f}× the cells"
        )
    for path in paths[1:]:
        big, small = by[(last, path, 0.0)], by[(first, path, 0.0)]
        checks = [
            (f"{last} ≤ 4 s", big.seconds <= 4.0), (f"{last} ≤ 2 GB", big.peak_rss_mb <= 2048.0),
            (f"{last} ≤ 4× {first}", big.seconds <= 4.0 * small.seconds), (f"{first} ≤ 1.2 s", small.seconds <= 1.2),
        ]  # fmt: skip
        verdicts = "; ".join(f"{name}: {'met' if ok else 'NOT met'}" for name, ok in checks)
        out.append(f"targets ({path} path): {verdicts}")
    return out


def write_scale_csv(rows: list[ScaleRow], path: Path) -> Path:
    """The rows with the columns of :class:`ScaleRow` (seconds, MB, metres in the names)."""
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=[f.name for f in fields(ScaleRow)])
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in asdict(row).items()})
    return path


def plot_scale(rows: list[ScaleRow], path: Path, note: str = "") -> Path:
    """Time and peak RSS against the grid's cells (size rows) and the workspace width (workspace rows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    paths = sorted({r.path for r in rows}, key=list(PATH_COLOURS).index)
    kitchen = [r for r in rows if r.grid.startswith("kitchen")]
    rows = [r for r in rows if not r.grid.startswith("kitchen")]
    for r in kitchen:  # the real room: one star per step, beside the tabletop curves
        ax_time, ax_rss, x = (
            (axes[0, 1], axes[1, 1], r.workspace_m) if r.workspace_m else (axes[0, 0], axes[1, 0], r.cells / 1e6)
        )
        for ax, y in ((ax_time, r.seconds), (ax_rss, r.peak_rss_mb / 1024)):
            ax.plot([x], [y], "*", markersize=12, color=PATH_COLOURS[r.path], label=f"kitchen, {r.path}")
    for path_name in paths:
        size_rows = [r for r in rows if r.path == path_name and not r.workspace_m]
        if size_rows:
            cells = [r.cells / 1e6 for r in size_rows]
            axes[0, 0].plot(cells, [r.seconds for r in size_rows], "o-", color=PATH_COLOURS[path_name], label=path_name)
            axes[1, 0].plot(cells, [r.peak_rss_mb / 1024 for r in size_rows], "o-", color=PATH_COLOURS[path_name],
                            label=path_name)  # fmt: skip
        work = [r for r in rows if r.path == path_name and r.workspace_m]
        if work:
            widths = [r.workspace_m for r in work]
            axes[0, 1].plot(widths, [r.seconds for r in work], "o-", color=PATH_COLOURS[path_name], label=path_name)
            axes[1, 1].plot(widths, [r.peak_rss_mb / 1024 for r in work], "o-", color=PATH_COLOURS[path_name],
                            label=path_name)  # fmt: skip
    axes[0, 0].set(title="grid size (every empty cell a candidate)", ylabel="one cnn_prob step (s)")
    axes[1, 0].set(xlabel="grid cells (millions)", ylabel="peak RSS (GiB)")
    largest = max((r.grid for r in rows if r.workspace_m), default="")
    axes[0, 1].set(title=f"workspace box on the {largest} grid", ylabel="one cnn_prob step (s)")
    axes[1, 1].set(xlabel="workspace width (m)", ylabel="peak RSS (GiB)")
    for ax in axes.ravel():
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(f"nbv bench --suite scale (2-core CPU, one run per point; {note})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
