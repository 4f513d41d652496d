"""Which surface blend ``beta`` (docs/method.md#surface-gain) finishes the surface in the fewest views (issue #45).

``cnn_surface`` explores 3DT worlds that are not in the held-out comparison (seeds 1000...; the
comparison uses 120...159) with the paper's loop (no view guard, as ``nbv evaluate``), once per
blend, each run from the same random first view. Per run and view: the surface coverage and the
unknown fraction (docs/evaluation.md#surface-coverage-and-chamfer-distance). Blend 0 is the
paper's gain on the CNN's map, i.e. ``cnn_prob``.

Writes ``runs.csv`` (seed, beta, view, coverage, unknown fraction, planning seconds),
``summary.csv`` (per beta: mean coverage after 5/10/15/20 views, views to 80/90/95 %, unknown
fraction at the end), ``summary.md`` and ``surface_blend.png``.

Run: ``nbv study surface_blend --seeds 1000 1001 1002 --views 20 --out studies/results/surface_blend``
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from nbv_prob_cnn.exploration.explore import explore
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.worlds import load_or_generate
from studies._command import run_command

HELP = "Which surface blend beta finishes the surface in the fewest views (3DT worlds outside the comparison)."
LEVELS = (0.8, 0.9, 0.95)
RUN_COLUMNS = ("seed", "beta", "view", "surface_coverage", "unknown_fraction", "planning_s")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", type=int, nargs="+", default=[1000, 1001, 1002])
    parser.add_argument("--betas", type=float, nargs="+", default=[0.0, 0.5, 0.8, 0.95, 1.0])
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--dataset", default="3dt", choices=("3dt", "3du"))
    parser.add_argument("--out", type=Path, default=Path("out/surface_blend"))


def views_to(coverage: np.ndarray, level: float) -> float:
    """The first view (1-based count of views taken) at which ``coverage`` reaches ``level``; NaN if never."""
    reached = np.flatnonzero(coverage >= level)
    return float(reached[0] + 1) if reached.size else float("nan")


def _load(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path) as handle:
        return list(csv.DictReader(handle))


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    args.out.mkdir(parents=True, exist_ok=True)
    runs_path = args.out / "runs.csv"
    rows = _load(runs_path)  # resumable: a (seed, beta) already stored is not run again
    done = {(int(r["seed"]), float(r["beta"])) for r in rows}
    todo = [(s, b) for s in args.seeds for b in args.betas if (s, b) not in done]
    for seed, beta in tqdm(todo, desc="runs", unit="run"):
        world = load_or_generate(args.dataset, seed)
        context = PlanningContext.for_dataset(args.dataset, rng=np.random.default_rng(seed),
                                              ground_truth=world.ground_truth, surface_blend=beta)  # fmt: skip
        start = time.perf_counter()
        result = explore(world, make_planner("cnn_surface"), context, args.views, progress=False)
        for record in result.records:
            rows.append({"seed": seed, "beta": beta, "view": record.iteration,
                         "surface_coverage": f"{record.surface_coverage:.6f}",
                         "unknown_fraction": f"{record.unknown_fraction:.6f}",
                         "planning_s": f"{record.time_total_s:.3f}"})  # fmt: skip
        with open(runs_path, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=RUN_COLUMNS)
            writer.writeheader()
            writer.writerows(rows)
        tqdm.write(f"seed {seed} beta {beta}: coverage {result.records[-1].surface_coverage:.4f} "
                   f"in {time.perf_counter() - start:.0f} s")  # fmt: skip
    write_summary(rows, args.out, args.views)
    return 0


def write_summary(rows: list[dict], out: Path, views: int) -> None:
    """``summary.csv``, ``summary.md`` and ``surface_blend.png`` of the stored runs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    betas = sorted({float(r["beta"]) for r in rows})
    after = [v for v in (5, 10, 15, 20, 30) if v <= views]
    table = []
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for beta in betas:
        runs: dict[int, list[tuple[int, float, float, float]]] = {}
        for r in rows:
            if float(r["beta"]) == beta:
                runs.setdefault(int(r["seed"]), []).append(
                    (int(r["view"]), float(r["surface_coverage"]), float(r["unknown_fraction"]), float(r["planning_s"]))
                )
        cov = np.array([[c for _, c, _, _ in sorted(v)] for v in runs.values() if len(v) == views])
        unk = np.array([[u for _, _, u, _ in sorted(v)] for v in runs.values() if len(v) == views])
        plan = np.array([[t for _, _, _, t in sorted(v)][1:] for v in runs.values() if len(v) == views])
        if cov.size == 0:
            continue
        entry = {"beta": beta, "runs": cov.shape[0]}
        for v in after:
            entry[f"coverage_after_{v}"] = float(cov[:, v - 1].mean())
        for level in LEVELS:
            reached = [views_to(c, level) for c in cov]
            entry[f"views_to_{int(level * 100)}"] = (
                float(np.nanmean(reached)) if not np.all(np.isnan(reached)) else float("nan")
            )
            entry[f"reached_{int(level * 100)}"] = int(np.sum(~np.isnan(reached)))
        entry["unknown_at_end"] = float(unk[:, -1].mean())
        entry["planning_s"] = float(plan.mean())
        table.append(entry)
        mean = cov.mean(axis=0) * 100
        ax.plot(np.arange(1, views + 1), mean, label=f"beta {beta:g}" + (" (cnn_prob)" if beta == 0 else ""))
    ax.set_xlabel("views taken (the random first one included)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.text(0.01, 0.01, "2-core CPU shared with other jobs: the summary's planning seconds compare nothing",
             fontsize=7, color="0.4")  # fmt: skip
    ax.set_ylabel("surface coverage (%), mean over the runs")
    ax.set_title(f"cnn_surface by blend, 3DT seeds {sorted({int(r['seed']) for r in rows})}, paper's loop")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "surface_blend.png", dpi=110)
    plt.close(fig)
    if not table:
        return
    with open(out / "summary.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(table[0]))
        writer.writeheader()
        writer.writerows(table)
    lines = ["| beta | runs | " + " | ".join(f"coverage after {v}" for v in after)
             + " | views to 80 / 90 / 95 % (reached) | unknown at the end | planning s |",
             "|---" * (len(after) + 5) + "|"]  # fmt: skip
    for e in table:
        reach = " / ".join(f"{e[f'views_to_{lv}']:.1f} ({e[f'reached_{lv}']})" for lv in (80, 90, 95))
        cells = " | ".join(f"{100 * e[f'coverage_after_{v}']:.1f} %" for v in after)
        lines.append(f"| {e['beta']:g} | {e['runs']} | {cells} | {reach} | {100 * e['unknown_at_end']:.2f} % "
                     f"| {e['planning_s']:.2f} |")  # fmt: skip
    (out / "summary.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    return run_command("surface_blend", HELP, add_arguments, run, argv)
