"""The surface-coverage side of a method comparison (:mod:`~nbv_prob_cnn.exploration.evaluation`):
a markdown table beside the unknown-fraction one (coverage after given numbers of views, the
views each method needs to reach 80 / 90 / 95 % coverage, the Chamfer distance where the runs
measured one), CSVs of the views to each level per method and per run, and a plot of coverage
against views.

A run that never reaches a level within its views is counted, never averaged: the views to a
level are the mean over the runs that reach it, next to how many of the runs do. A run CSV written
before the ``surface_coverage`` column makes its method's coverage cells ``n/a``, saying so.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from nbv_prob_cnn.exploration.evaluation import RunLog, coverage_curves
from nbv_prob_cnn.exploration.surface_metrics import views_to_coverage

#: The coverage levels reported.
LEVELS = (0.8, 0.9, 0.95)
#: What a coverage cell says when run CSVs lack the column.
PREDATES = "run CSV predates the column"


@dataclass
class LevelReached:
    """The views each run took to reach one coverage level (only the runs that reached it)."""

    level: float
    runs: int
    views: list[int]

    def cell(self) -> str:
        """``12.3 ± 4.1 (9/10)``: mean ± std over the runs that reach it (reached/runs)."""
        if not self.views:
            return f"never (0/{self.runs})"
        values = np.asarray(self.views, dtype=np.float64)
        return f"{values.mean():.1f} ± {values.std():.1f} ({len(values)}/{self.runs})"


def levels_reached(runs: list[RunLog], levels: Sequence[float] = LEVELS) -> list[LevelReached] | None:
    """Per level, the views to it of the runs that reach it; None when a run CSV predates the column."""
    if any(r.surface_coverage is None for r in runs):
        return None
    reached = [views_to_coverage(r.surface_coverage, levels) for r in runs if r.surface_coverage is not None]
    return [LevelReached(level, len(runs), [n for r in reached if (n := r[level]) is not None]) for level in levels]


def _missing(runs: list[RunLog]) -> str:
    without = sum(r.surface_coverage is None for r in runs)
    if without == len(runs):
        return f"n/a ({PREDATES})"
    return f"n/a ({without} of {len(runs)} run CSVs predate the column)"


def _chamfer_cell(runs: list[RunLog]) -> str:
    """Mean ± std of the Chamfer distance (mm), and of its accuracy / completeness terms."""
    measured = [r.chamfer for r in runs if r.chamfer is not None]
    if len(measured) < len(runs):
        return f"n/a ({len(runs) - len(measured)} of {len(runs)} runs without one)"
    finite = [m for m in measured if np.isfinite(m["distance_m"])]
    if not finite:
        return "n/a (no TSDF surface)"

    def mm(key: str) -> np.ndarray:
        return 1000.0 * np.array([m[key] for m in finite])

    distance, accuracy, completeness = mm("distance_m"), mm("accuracy_m"), mm("completeness_m")
    cell = f"{distance.mean():.2f} ± {distance.std():.2f} ({accuracy.mean():.2f} / {completeness.mean():.2f})"
    return cell if len(finite) == len(runs) else f"{cell}, {len(runs) - len(finite)} runs without surface"


def coverage_table(logs: dict[str, list[RunLog]], at_views: list[int], levels: Sequence[float] = LEVELS) -> str:
    """Markdown: per method the surface coverage after each of ``at_views`` views (mean ± std), the
    views to each of ``levels`` (module docstring) and, when any run measured one, the Chamfer
    distance after the last view; a legend line below."""
    with_chamfer = any(r.chamfer is not None for runs in logs.values() for r in runs)
    titles = [f"coverage after {v} views" for v in at_views] + [f"views to {round(100 * lv)} %" for lv in levels]
    if with_chamfer:
        titles.append("Chamfer after the last view, mm (accuracy / completeness)")
    lines = ["| method | runs | " + " | ".join(titles) + " |", "|---|---|" + "---|" * len(titles)]
    for method, runs in logs.items():
        curves = coverage_curves(runs, max(at_views))
        reached = levels_reached(runs, levels)
        if curves is None or reached is None:
            cells = [_missing(runs)] * (len(at_views) + len(levels))
        else:
            cells = [f"{curves[:, v - 1].mean():.4f} ± {curves[:, v - 1].std():.4f}" for v in at_views]
            cells += [r.cell() for r in reached]
        if with_chamfer:
            cells.append(_chamfer_cell(runs))
        lines.append(f"| {method} | {len(runs)} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Surface coverage: the share of the ground-truth surface cells facing the first view's free space that lie "
        "within one cell of a cell seen occupied (mean ± std over the runs). Views to a level: mean ± std over the "
        "runs that reach it (reached/runs); a run that never reaches it counts in the runs, not in the mean."
        + (" Chamfer: the TSDF mesh of the views against the ground-truth meshes where they face that free space, "
           "mean ± std over the runs." if with_chamfer else ""),
    ]  # fmt: skip
    return "\n".join(lines)


def write_views_to_coverage_csv(logs: dict[str, list[RunLog]], path: Path, levels: Sequence[float] = LEVELS) -> None:
    """Per method and level: runs, runs that reach it, and the mean / std / median / max of their
    views to it (empty when none does; ``n/a`` when a run CSV predates the column)."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["method", "level", "runs", "runs_reaching", "mean_views", "std_views", "median_views",
                         "max_views"])  # fmt: skip
        for method, runs in logs.items():
            reached = levels_reached(runs, levels)
            for index, level in enumerate(levels):
                if reached is None:
                    writer.writerow([method, level, len(runs), "n/a", "n/a", "n/a", "n/a", "n/a"])
                    continue
                views = np.asarray(reached[index].views, dtype=np.float64)
                stats = (
                    [f"{views.mean():.2f}", f"{views.std():.2f}", f"{np.median(views):g}", f"{views.max():g}"]
                    if views.size
                    else ["", "", "", ""]
                )
                writer.writerow([method, level, len(runs), views.size, *stats])


def write_coverage_runs_csv(logs: dict[str, list[RunLog]], path: Path, levels: Sequence[float] = LEVELS) -> None:
    """One row per run: its views, final coverage, views to each level (``never``; ``n/a`` when its
    CSV predates the column) and its Chamfer distance and terms in metres (empty without one)."""
    percents = [round(100 * level) for level in levels]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["method", "seed", "views", "final_surface_coverage", *(f"views_to_{p}" for p in percents),
                         "chamfer_m", "accuracy_m", "completeness_m"])  # fmt: skip
        for method, runs in logs.items():
            for run in runs:
                final, to = "n/a", ["n/a"] * len(levels)
                if run.surface_coverage is not None:
                    final = f"{run.surface_coverage[-1]:.6f}"
                    reached = views_to_coverage(run.surface_coverage, levels).values()
                    to = ["never" if n is None else str(n) for n in reached]
                chamfer = run.chamfer or {}
                metres = [
                    f"{chamfer[k]:.6f}" if k in chamfer else "" for k in ("distance_m", "accuracy_m", "completeness_m")
                ]
                seed = "" if run.seed is None else run.seed
                writer.writerow([method, seed, len(run.unknown_fraction), final, *to, *metres])


def save_coverage_plot(
    logs: dict[str, list[RunLog]], views: int, title: str, path: Path, levels: Sequence[float] = LEVELS
) -> Path | None:
    """Surface coverage (%) against views per method (mean ± std), the levels as dotted lines, and
    the views to each level per method (mean over the runs that reach it, labelled reached/runs).
    None (nothing written) when no method has coverage."""
    covered = {m: c for m, runs in logs.items() if (c := coverage_curves(runs, views)) is not None}
    methods = {m: logs[m] for m in covered}
    if not methods:
        return None
    fig = Figure(figsize=(13, 5))
    ax_curve, ax_levels = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    x = np.arange(1, views + 1)
    width = 0.8 / len(methods)
    for index, (method, runs) in enumerate(methods.items()):
        curves = 100.0 * covered[method]
        mean, std = curves.mean(axis=0), curves.std(axis=0)
        (line,) = ax_curve.plot(x, mean, label=method)
        ax_curve.fill_between(x, np.clip(mean - std, 0, 100), np.clip(mean + std, 0, 100), alpha=0.12)
        reached = levels_reached(runs, levels) or []
        positions = np.arange(len(levels)) + (index - (len(methods) - 1) / 2) * width
        heights = [float(np.mean(r.views)) if r.views else 0.0 for r in reached]
        bars = ax_levels.bar(positions, heights, width, color=line.get_color(), label=method)
        labels = [f"{len(r.views)}/{r.runs}" for r in reached]
        ax_levels.bar_label(bars, labels=labels, fontsize=6, rotation=90, padding=2)
    for level in levels:
        ax_curve.axhline(100 * level, color="grey", lw=0.6, ls=":")
    ax_curve.set_xlabel("views")
    ax_curve.set_ylabel("surface coverage (% of the visible ground-truth surface cells)")
    ax_curve.set_title(f"{title}: surface coverage (mean ± std over environments)")
    ax_curve.set_ylim(0, 100)
    ax_curve.grid(alpha=0.3)
    ax_curve.legend(fontsize=8)
    ax_levels.set_xticks(np.arange(len(levels)), [f"{round(100 * level)} %" for level in levels])
    ax_levels.set_xlabel("coverage level")
    ax_levels.set_ylabel("views to reach it (mean over the runs that do)")
    ax_levels.set_title("views to a coverage level (label: runs reaching it / runs)")
    ax_levels.grid(alpha=0.3, axis="y")
    ax_levels.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return path
