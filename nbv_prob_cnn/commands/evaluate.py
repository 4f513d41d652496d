"""``nbv evaluate``: compare methods on held-out environments (SPEC §9)."""

from __future__ import annotations

import argparse
from pathlib import Path

from nbv_prob_cnn.camera import DATASETS

NAME = "evaluate"
HELP = "Compare NBV methods on held-out environments: per-run CSVs, summary table, plots (resumable)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from nbv_prob_cnn.evaluation import DEFAULT_SEEDS

    parser.add_argument("--dataset", choices=sorted(DATASETS), required=True)
    parser.add_argument(
        "--methods", nargs="+", default=["random", "ig", "prob_ig", "cnn_prob", "cnn_prob_d", "omniscient"]
    )
    parser.add_argument("--seeds", nargs="+", type=int, default=list(DEFAULT_SEEDS), help="environment seeds")
    parser.add_argument("--views", type=int, default=50)
    parser.add_argument("--at", nargs="+", type=int, default=[20, 50], help="table columns: after N views")
    parser.add_argument("--out", default="out/evaluation", help="output directory (runs are cached there)")


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.evaluation import evaluate, save_plots, summary_table, write_summary_csv

    if any(a < 1 or a > args.views for a in args.at):
        raise ValueError(f"--at: every value must be within 1..{args.views}")
    out = Path(args.out) / args.dataset
    logs = evaluate(args.dataset, args.methods, args.seeds, args.views, out)
    table = summary_table(logs, args.at)
    write_summary_csv(logs, args.views, out / f"{args.dataset}_summary.csv")
    (out / f"{args.dataset}_table.md").write_text(table + "\n")
    plots = save_plots(logs, args.views, args.dataset, out)
    print(table)
    print(
        f"wrote {out / f'{args.dataset}_summary.csv'}, {out / f'{args.dataset}_table.md'}, "
        + ", ".join(map(str, plots))
    )
    return 0
