"""The method comparison of SPEC §9: every method on the same held-out environments, one CSV
per run, then mean/spread curves (paper Fig. 5), time against explored fraction (Fig. 6) and
a table of the unknown fraction after given numbers of views.

Runs are resumable: a run whose CSV exists is read back instead of recomputed.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from nbv_prob_cnn.camera import dataset_defaults
from nbv_prob_cnn.explore import explore, write_csv
from nbv_prob_cnn.planners import PlanningContext, make_planner

#: Evaluation environments: the first ten seeds of the CNN test split (never trained on).
DEFAULT_SEEDS = tuple(range(120, 130))


@dataclass
class RunLog:
    """Per-view columns of one run, as read from its CSV."""

    unknown_fraction: np.ndarray
    unknown_fraction_all: np.ndarray
    time_total_s: np.ndarray


def read_run(path: Path) -> RunLog:
    with open(path) as handle:
        rows = list(csv.DictReader(handle))
    column = lambda name: np.array([float(r[name]) for r in rows])  # noqa: E731
    return RunLog(column("unknown_fraction"), column("unknown_fraction_all"), column("time_total_s"))


def run_path(out: Path, dataset: str, method: str, seed: int) -> Path:
    return out / "runs" / f"{dataset}_{method}_seed{seed}.csv"


def evaluate(
    dataset: str, methods: list[str], seeds: list[int], views: int, out: Path, progress: bool = True
) -> dict[str, list[RunLog]]:
    """Run (or read back) every method on every seed; returns the logs per method."""
    from nbv_prob_cnn.worlds import load_or_generate

    defaults = dataset_defaults(dataset)
    for method in methods:
        make_planner(method)  # fail early on an unknown name
    (out / "runs").mkdir(parents=True, exist_ok=True)
    logs: dict[str, list[RunLog]] = {m: [] for m in methods}
    jobs = [(seed, method) for seed in seeds for method in methods]
    bar = tqdm(jobs, desc=f"evaluate {dataset}", unit="run", disable=not progress)
    for seed, method in bar:
        path = run_path(out, dataset, method, seed)
        if not path.exists():
            world = load_or_generate(dataset, seed)
            # same first view for every method: the rng is seeded by the environment only
            context = PlanningContext(defaults, rng=np.random.default_rng(seed), ground_truth=world.ground_truth)
            result = explore(world, make_planner(method), context, views, progress=False)
            tmp = path.with_suffix(".tmp")
            write_csv(result.records, tmp)
            tmp.replace(path)
        logs[method].append(read_run(path))
        bar.set_postfix(seed=seed, method=method)
    return logs


def padded(values: list[np.ndarray], length: int) -> np.ndarray:
    """Stack per-view curves; a run that stopped early keeps its last value."""
    return np.array(
        [np.concatenate([v, np.full(length - len(v), v[-1])]) if len(v) < length else v[:length] for v in values]
    )


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


def save_plots(logs: dict[str, list[RunLog]], views: int, dataset: str, out: Path) -> list[Path]:
    """Unknown fraction per view (mean ± std) and planning time against explored fraction."""
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
    ax_curve.set_title(f"{dataset.upper()}: unknown fraction (mean ± std over environments)")
    ax_curve.grid(alpha=0.3)
    ax_curve.legend()
    ax_time.set_xlabel("explored cells before planning (%)")
    ax_time.set_ylabel("planning time per view (s)")
    ax_time.set_title("computation time per iteration")
    ax_time.grid(alpha=0.3)
    ax_time.legend()
    fig.tight_layout()
    path = out / f"{dataset}_comparison.png"
    fig.savefig(path, dpi=90)
    return [path]


def write_summary_csv(logs: dict[str, list[RunLog]], views: int, path: Path) -> None:
    """Per view and method: mean and std of the unknown fraction."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["method", "view", "runs", "mean_unknown_fraction", "std_unknown_fraction"])
        for method, runs in logs.items():
            curves = padded([r.unknown_fraction for r in runs], views)
            for v in range(views):
                writer.writerow([method, v + 1, len(runs), f"{curves[:, v].mean():.6f}", f"{curves[:, v].std():.6f}"])
