"""Paper against original gain variant (issue 23, docs/original_code.md), from stored runs only.

Reads the runs of ``nbv evaluate`` (default ``--gain-variant paper``) under ``paper_dir`` and of
``nbv evaluate --gain-variant original`` under ``original_dir``, for the environments where both
variants have every method's run, and writes beside the original runs
``<dataset>_paper_vs_original.{md,csv,png}``: mean ± std of the unknown fraction after given
numbers of views per method and variant, the mean paired difference (same environment, same
first view) with its standard error, and the mean curves. Nothing is run or rewritten elsewhere.

    nbv study variant_comparison --dataset 2d \\
        --paper studies/results/evaluation --original studies/results/evaluation_original
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from nbv_prob_cnn.basics.datasets import EVALUATION_SEEDS
from nbv_prob_cnn.exploration.evaluation import padded, paired_difference, read_run, run_path, run_status

METHODS = ("prob_ig", "cnn_prob", "omniscient")
VARIANTS = ("paper", "original")


def common_seeds(dataset: str, dirs: dict[str, Path], methods: tuple[str, ...], views: int) -> list[int]:
    """Environments whose runs of every method exist for ``views`` views in both variants."""

    def done(variant: str, method: str, seed: int) -> bool:
        status = run_status(run_path(dirs[variant], dataset, method, seed), views, None, variant)
        return status in ("done", "other weights")  # weights: the comparison reads what was run

    return [s for s in EVALUATION_SEEDS if all(done(v, m, s) for v in VARIANTS for m in methods)]


def compare(
    dataset: str, dirs: dict[str, Path], methods: tuple[str, ...] = METHODS, views: int = 100,
    at: tuple[int, ...] = (20, 50, 100),
) -> tuple[str, str, dict[tuple[str, str], np.ndarray], list[int]]:  # fmt: skip
    """Markdown table, CSV text, the ``(variant, method) -> (runs, views)`` curves and the seeds."""
    seeds = common_seeds(dataset, dirs, methods, views)
    if not seeds:
        raise ValueError(f"{dataset}: no environment has every method's run in both variants")
    curves, times = {}, {}
    for variant in VARIANTS:
        for method in methods:
            logs = [read_run(run_path(dirs[variant], dataset, method, s), views) for s in seeds]
            curves[(variant, method)] = padded([r.unknown_fraction for r in logs], views)
            times[(variant, method)] = np.concatenate([r.time_total_s[1:] for r in logs])
    intro = (
        f"Unknown fraction of the ground-truth-empty cells, mean ± std over {len(seeds)} environments "
        f"({', '.join(map(str, seeds))}); 'original − paper': the mean paired difference ± its standard "
        "error (same environment, same first view)."
    )
    columns = " | ".join(f"after {a} views" for a in at)
    lines = [intro, "", f"| method | gain variant | runs | {columns} | mean planning time (s) |",
             "|---|---|---|" + "---|" * len(at) + "---|"]  # fmt: skip
    rows = ["method,gain_variant,runs," + ",".join(f"mean_after_{a},std_after_{a}" for a in at)]
    for method in methods:
        for variant in VARIANTS:
            c = curves[(variant, method)]
            cells = " | ".join(f"{c[:, a - 1].mean():.4f} ± {c[:, a - 1].std():.4f}" for a in at)
            lines.append(f"| {method} | {variant} | {len(seeds)} | {cells} | {times[(variant, method)].mean():.3f} |")
            stats = ",".join(f"{c[:, a - 1].mean():.5f},{c[:, a - 1].std():.5f}" for a in at)
            rows.append(f"{method},{variant},{len(seeds)},{stats}")
        mean, error = paired_difference(curves[("original", method)], curves[("paper", method)])
        cells = " | ".join(f"{mean[a - 1]:+.4f} ± {error[a - 1]:.4f}" for a in at)
        lines.append(f"| {method} | original − paper | {len(seeds)} | {cells} | |")
        rows.append(f"{method},original-paper,{len(seeds)}," + ",".join(
            f"{mean[a - 1]:.5f},{error[a - 1]:.5f}" for a in at))  # fmt: skip
    return "\n".join(lines) + "\n", "\n".join(rows) + "\n", curves, seeds


def save_curves(curves: dict[tuple[str, str], np.ndarray], dataset: str, seeds: list[int], path: Path) -> None:
    """Mean unknown fraction per view, paper (solid) and original (dashed) per method."""
    fig = Figure(figsize=(7.5, 4.8))
    ax = fig.add_subplot(1, 1, 1)
    methods = list(dict.fromkeys(method for _, method in curves))
    for i, method in enumerate(methods):
        for variant, style in (("paper", "-"), ("original", "--")):
            mean = curves[(variant, method)].mean(axis=0) * 100
            ax.plot(np.arange(1, mean.size + 1), mean, style, color=f"C{i}", label=f"{method} ({variant})")
    ax.set_xlabel("views")
    ax.set_ylabel("unknown ground-truth-empty cells (%, mean)")
    ax.set_title(f"{dataset.upper()}: paper gain vs the original code's host choices ({len(seeds)} environments)",
                 fontsize=10)  # fmt: skip
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--paper", default="studies/results/evaluation", help="out folder of the paper-variant runs")
    parser.add_argument(
        "--original", default="studies/results/evaluation_original", help="out folder of the original runs"
    )
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--at", nargs="+", type=int, default=[20, 50, 100], help="table columns: after N views")
    args = parser.parse_args(argv)
    if any(not 1 <= a <= args.views for a in args.at):
        raise ValueError(f"--at: every value must lie within 1..{args.views}, got {args.at}")
    dirs = {"paper": Path(args.paper) / args.dataset, "original": Path(args.original) / args.dataset}
    table, rows, curves, seeds = compare(args.dataset, dirs, tuple(args.methods), args.views, tuple(args.at))
    stem = dirs["original"] / f"{args.dataset}_paper_vs_original"
    stem.with_suffix(".md").write_text(table)
    stem.with_suffix(".csv").write_text(rows)
    save_curves(curves, args.dataset, seeds, stem.with_suffix(".png"))
    print(table)
    print(f"wrote {stem}.md, .csv, .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
