"""``nbv evaluate``: compare methods on held-out environments
(docs/method.md#exploration-protocol-and-metrics), runs as Ray tasks."""

from __future__ import annotations

import argparse
from pathlib import Path

from nbv_prob_cnn.basics.datasets import DATASET_SPECS, EVALUATION_SEEDS

NAME = "evaluate"
HELP = "Compare NBV methods on held-out environments as Ray tasks: per-run CSVs, summary table, plots (resumable)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from nbv_prob_cnn.gain import BACKENDS, GAIN_VARIANTS
    from nbv_prob_cnn.planners import METHODS
    from nbv_prob_cnn.planners.registry import PAPER_METHODS

    parser.add_argument("--dataset", choices=sorted(DATASET_SPECS), required=True)
    parser.add_argument(
        "--methods", nargs="+", default=list(PAPER_METHODS), choices=list(METHODS), metavar="METHOD",
        help=f"methods to compare (default: the paper's nine: {' '.join(PAPER_METHODS)}; also: "
        f"{' '.join(m for m in METHODS if m not in PAPER_METHODS)})",
    )  # fmt: skip
    parser.add_argument(
        "--seeds", nargs="+", type=int, default=list(EVALUATION_SEEDS),
        help="environment seeds (default: the protocol's 40 test environments 120..159)",
    )  # fmt: skip
    parser.add_argument("--envs", type=int, default=None, help="use only the first N of --seeds")
    parser.add_argument("--views", type=int, default=100, help="views per run, the random first one included")
    parser.add_argument("--at", nargs="+", type=int, default=None, help="table columns: after N views")
    parser.add_argument(
        "--out", default="out/evaluation",
        help="output directory (runs are cached there; redone when the weights they ran with have changed)",
    )  # fmt: skip
    parser.add_argument(
        "--workers", type=int, default=None,
        help="local Ray instance with N CPUs (default: all cores); 0 = no Ray, runs one by one in this process",
    )  # fmt: skip
    parser.add_argument("--address", default=None, help="an existing Ray cluster, e.g. 10.0.0.5:6379")
    parser.add_argument("--backend", choices=BACKENDS, default="auto", help="ray-casting backend of the runs")
    parser.add_argument(
        "--gain-variant", choices=GAIN_VARIANTS, default="paper",
        help="gain of the runs: the paper's equations, or the authors' code's host choices (docs/original_code.md)",
    )  # fmt: skip
    parser.add_argument(
        "--guard", action="store_true",
        help="run every method with the view guard (a pose whose view changed fewer than --guard-min-cells cells "
        "is never planned again); results as <dataset>_guarded_* beside the plain ones. Default: the paper's loop",
    )  # fmt: skip
    parser.add_argument("--guard-min-cells", type=int, default=None,
                        help="with --guard: threshold in cells (default: 5e-5 of the grid's cells)")  # fmt: skip
    parser.add_argument(
        "--chamfer", action="store_true",
        help="3D: every run also fuses a depth image of the world's meshes per view into a TSDF and stores the Chamfer "
        "distance of its mesh to them after the last view (a stored run without one is redone)",
    )  # fmt: skip
    parser.add_argument(
        "--replay", default=None, metavar="DIR",
        help="replay the stored runs of DIR (e.g. studies/results/evaluation) instead of planning: the same views, "
        "their surface coverage (and with --chamfer the Chamfer distance) measured anew, stored under --out",
    )  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.exploration.coverage_tables import (
        coverage_table,
        save_coverage_plot,
        write_coverage_runs_csv,
        write_views_to_coverage_csv,
    )
    from nbv_prob_cnn.exploration.evaluation import (
        GUARDED,
        evaluate,
        save_plots,
        summary_table,
        write_summary_csv,
    )

    at = args.at or sorted({min(20, args.views), min(50, args.views), args.views})
    if args.views < 1 or any(a < 1 or a > args.views for a in at):
        raise ValueError(f"--views must be >= 1 and every --at value within 1..{args.views}")
    if args.workers is not None and args.workers < 0:
        raise ValueError("--workers: expected >= 0")
    if args.guard_min_cells is not None and not args.guard:
        raise ValueError("--guard-min-cells needs --guard")
    seeds = args.seeds[: args.envs] if args.envs else args.seeds
    out = Path(args.out) / args.dataset
    logs = evaluate(
        args.dataset, args.methods, seeds, args.views, out, progress=not args.quiet,
        workers=args.workers, address=args.address, backend=args.backend, gain_variant=args.gain_variant,
        guard=args.guard, guard_min_cells=args.guard_min_cells, chamfer=args.chamfer,
        replay=None if args.replay is None else Path(args.replay) / args.dataset,
    )  # fmt: skip
    table = summary_table(logs, at) + "\n\n" + coverage_table(logs, at)
    stem = f"{args.dataset}_{GUARDED}" if args.guard else args.dataset
    written = [out / f"{stem}_summary.csv", out / f"{stem}_table.md", out / f"{stem}_views_to_coverage.csv",
               out / f"{stem}_coverage_runs.csv"]  # fmt: skip
    write_summary_csv(logs, args.views, written[0])
    written[1].write_text(table + "\n")
    write_views_to_coverage_csv(logs, written[2])
    write_coverage_runs_csv(logs, written[3])
    written += save_plots(logs, args.views, args.dataset, out, stem)
    title = args.dataset.upper() + (", guarded" if args.guard else "")
    coverage_png = save_coverage_plot(logs, args.views, title, out / f"{stem}_coverage.png")
    written += [] if coverage_png is None else [coverage_png]
    print(table)
    print("wrote " + ", ".join(map(str, written)))
    return 0
