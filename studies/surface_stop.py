"""What the surface stop rule saves and loses (issue #45): views saved against coverage lost, from runs.

A run CSV made with a stop rule logs, per view, the most new surface a view could add
(``new_surface_cells``, :func:`~nbv_prob_cnn.planners.surface_stop.best_new_surface`); ``--replay``
makes it again for runs without it. The stop rule with a threshold of ``T`` cells ends a run before
the first view whose estimate is below ``T``
(:class:`~nbv_prob_cnn.planners.surface_stop.SurfaceStop`; the views before are the same as without
the rule, so a run to the full budget shows where each threshold would have stopped it). Per
threshold: the runs it stops, the mean views taken, the views saved against the budget and the
surface coverage lost (coverage after the budget minus coverage at the stop), mean and worst.

Run: ``nbv study surface_stop --runs out/evaluation/3dt/runs --method cnn_surface --views 30
--out studies/results/surface_stop/3dt``
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from studies._command import run_command

HELP = "What the surface stop rule saves and loses: views saved against coverage lost, from runs to the budget."


@dataclass(frozen=True)
class StopRow:
    """One threshold over the runs (see the module doc)."""

    threshold_cells: float
    runs: int
    stopped: int
    mean_views: float
    views_saved: float
    coverage_lost_mean: float
    coverage_lost_max: float
    coverage_at_stop: float


def stop_view(estimates: list[float], threshold: float) -> int | None:
    """Views taken when the rule stops (``estimates`` per view, NaN where none: never stops there);
    None when it never stops within the run."""
    for view, estimate in enumerate(estimates):
        if np.isfinite(estimate) and estimate < threshold:
            return view
    return None


def analyse(runs: list[tuple[list[float], list[float]]], thresholds: list[float]) -> list[StopRow]:
    """Per threshold a :class:`StopRow` of ``runs``, each ``(estimates, coverage)`` per view."""
    out = []
    for threshold in thresholds:
        views, lost, at_stop, stopped = [], [], [], 0
        for estimates, coverage in runs:
            stop = stop_view(estimates, threshold)
            taken = len(coverage) if stop is None else max(stop, 1)
            stopped += stop is not None
            views.append(taken)
            at_stop.append(coverage[taken - 1])
            lost.append(coverage[-1] - coverage[taken - 1])
        budget = len(runs[0][1])
        out.append(StopRow(threshold, len(runs), stopped, float(np.mean(views)), budget - float(np.mean(views)),
                           float(np.mean(lost)), float(np.max(lost)), float(np.mean(at_stop))))  # fmt: skip
    return out


def run_paths(folder: Path, method: str, guarded: bool = False) -> list[Path]:
    """The run CSVs of ``method`` in ``folder`` in name order (``guarded``: its runs with the view guard)."""
    return sorted(folder.glob(f"*_{method}{'_guarded' if guarded else ''}_seed*.csv"))


def read_runs(
    folder: Path, method: str, views: int, require_estimates: bool = True, guarded: bool = False
) -> list[tuple[list[float], list[float]]]:
    """``(estimates, coverage)`` of every run CSV of ``method`` in ``folder`` (all of them, in name
    order: each must hold ``views`` views and, with ``require_estimates``, the estimates)."""
    found = []
    for path in run_paths(folder, method, guarded):
        with open(path, newline="") as handle:
            rows = list(csv.DictReader(handle))[:views]
        if len(rows) < views or (require_estimates and "new_surface_cells" not in rows[0]):
            raise ValueError(f"{path}: fewer than {views} views, or no new_surface_cells column")
        logged = [r.get("new_surface_cells", "") for r in rows]
        estimates = [float(v) if v else float("nan") for v in logged]
        found.append((estimates, [float(r["surface_coverage"]) for r in rows]))
    if not found:
        raise ValueError(f"--runs {folder}: no run of {method} with {views} views and a new_surface_cells column")
    return found


def replayed_estimates(path: Path, dataset: str, method: str, views: int, below: float = 0.0) -> list[float]:
    """The estimates of a stored run's views made again with today's estimator: its views taken again
    on the world (as ``nbv evaluate --replay``), before each one the method's map of the grid so far
    and the view's :func:`~nbv_prob_cnn.planners.surface_stop.predicted_new_surface` (NaN for the
    random first view; the stored view itself is not needed: the estimate is the most surface any
    candidate view could add, :func:`~nbv_prob_cnn.planners.surface_stop.best_new_surface`). Once an
    estimate is below ``below`` (the smallest threshold: every threshold has stopped the run by then)
    the later views get NaN, not estimated."""
    from nbv_prob_cnn.exploration.replay import POSE_COLUMNS, read_rows, view_of_row
    from nbv_prob_cnn.planners import PlanningContext
    from nbv_prob_cnn.planners.methods import GAIN_METHODS, GainPlanner, probability_map
    from nbv_prob_cnn.planners.surface_stop import best_new_surface
    from nbv_prob_cnn.sensing.observe import observe
    from nbv_prob_cnn.worlds import load_or_generate

    seed = int(path.stem.rsplit("seed", 1)[1])
    world = load_or_generate(dataset, seed)
    context = PlanningContext.for_dataset(dataset, rng=np.random.default_rng(seed), ground_truth=world.ground_truth)
    header, rows = read_rows(path, views)
    state = np.full(world.shape, -1, dtype=np.int8)
    estimates = []
    for number, values in enumerate(rows):
        row = dict(zip(header, values, strict=True))
        cell, view = view_of_row([row[k] for k in POSE_COLUMNS], world, context)
        if number == 0:
            estimates.append(float("nan"))
        else:
            prob = probability_map(GAIN_METHODS[method], state, context)
            assert prob is not None  # a probabilistic method's map
            origins = GainPlanner(GAIN_METHODS[method]).candidates(state, context)
            estimates.append(best_new_surface(state, prob, origins, context))
            if estimates[-1] < below:
                return estimates + [float("nan")] * (len(rows) - len(estimates))
        observe(state, world.ground_truth, cell, context.orientations[view], context.active_sensor)
    return estimates


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--runs", type=Path, required=True, help="folder of run CSVs (nbv evaluate's <out>/<dataset>/runs)"
    )
    parser.add_argument("--method", default="cnn_surface")
    parser.add_argument("--views", type=int, default=30, help="the budget the runs went to")
    parser.add_argument("--thresholds", type=float, nargs="+", default=[5, 10, 20, 50, 100, 200])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--guarded", action="store_true", help="the method's runs with the view guard")
    parser.add_argument("--replay", metavar="DATASET", help="make each view's estimate again with today's estimator "
                        "on the runs' worlds (the runs of DATASET), instead of reading new_surface_cells")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    runs = read_runs(args.runs, args.method, args.views, require_estimates=args.replay is None, guarded=args.guarded)
    if args.replay is not None:
        paths = run_paths(args.runs, args.method, args.guarded)
        pairs = tqdm(list(zip(paths, runs, strict=True)), desc="replay", unit="run")
        runs = [(replayed_estimates(path, args.replay, args.method, args.views, min(args.thresholds)), coverage)
                for path, (_, coverage) in pairs]  # fmt: skip
    rows = analyse(runs, args.thresholds)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "stop.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(asdict(rows[0])))
        writer.writeheader()
        writer.writerows(asdict(r) for r in rows)
    lines = [
        (f"{args.method}{' (view guard)' if args.guarded else ''}, {rows[0].runs} runs to {args.views} views "
         f"({args.runs})"), "",
        ("| stop below (cells) | runs stopped | views taken | views saved | coverage at the stop "
        "| coverage lost, mean / worst |"),
        "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for r in rows:
        lines.append(f"| {r.threshold_cells:g} | {r.stopped}/{r.runs} | {r.mean_views:.1f} | {r.views_saved:.1f} "
                     f"| {100 * r.coverage_at_stop:.2f} % | {100 * r.coverage_lost_mean:.2f} / "
                     f"{100 * r.coverage_lost_max:.2f} points |")  # fmt: skip
    (args.out / "stop.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command("surface_stop", HELP, add_arguments, run, argv)
