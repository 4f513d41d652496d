"""The paper's plain loop against the view guard (issue 19), from stored runs only.

Reads the plain and the guarded runs of ``nbv evaluate`` (``--guard``) under ``out`` for the
environments where both exist for every method, and writes beside them
``<dataset>_guarded_vs_plain.{md,csv}``: per method the mean unknown fraction after given numbers
of views in each loop, the mean paired difference (same environment, same first view) with its
standard error, and how many guarded runs stopped early (nothing left to plan).

    nbv study guard_comparison --dataset 2d --out studies/results/evaluation
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nbv_prob_cnn.basics.datasets import EVALUATION_SEEDS
from nbv_prob_cnn.exploration.evaluation import padded, paired_difference, read_run, run_path

METHODS = ("random", "ig", "prob_ig", "cnn_prob", "cnn_prob_d", "omniscient", "flat_city_cnn", "b_city_cnn",
           "d_city_cnn")  # fmt: skip


def compare(dataset: str, out: Path, methods=METHODS, views: int = 100, at=(20, 50, 100)) -> tuple[str, str]:
    """Markdown and CSV text of the comparison (see the module doc).

    Raises:
        ValueError: no environment has both runs of every method.
    """
    seeds = [s for s in EVALUATION_SEEDS
             if all(run_path(out, dataset, m, s, g).is_file() for m in methods for g in (False, True))]  # fmt: skip
    if not seeds:
        raise ValueError(f"{dataset}: no environment has the plain and the guarded run of every method under {out}")
    columns = " | ".join(f"after {a}" for a in at)
    intro = (
        f"Unknown fraction of the ground-truth-empty cells, mean over {len(seeds)} environments "
        f"({', '.join(map(str, seeds))}); 'guarded − plain': mean paired difference ± its standard error."
    )
    lines = [
        intro,
        "",
        f"| method | loop | {columns} | guarded runs stopped early |",
        "|---|---|" + "---|" * len(at) + "---|",
    ]
    rows = ["method,loop,runs," + ",".join(f"after_{a},error_after_{a}" for a in at) + ",stopped_early"]
    for method in methods:
        logs = {g: [read_run(run_path(out, dataset, method, s, g), views) for s in seeds] for g in (False, True)}
        curves = {g: padded([r.unknown_fraction for r in logs[g]], views) for g in logs}
        stopped = sum(len(r.unknown_fraction) < views for r in logs[True])
        mean, error = paired_difference(curves[True], curves[False])
        for label, c in (("plain", curves[False]), ("guarded", curves[True])):
            means = [c[:, a - 1].mean() for a in at]
            early = str(stopped) if label == "guarded" else ""
            lines.append(
                f"| {method} | {label} | "
                + " | ".join(f"{m:.4f}" for m in means)
                + (f" | {early} |" if early else " | |")
            )
            fields = [f for m in means for f in (f"{m:.5f}", "")]  # no error column for one loop
            rows.append(",".join([method, label, str(len(seeds)), *fields, early]))
        cells = " | ".join(f"{mean[a - 1]:+.4f} ± {error[a - 1]:.4f}" for a in at)
        lines.append(f"| {method} | guarded − plain | {cells} | |")
        values = ",".join(f"{mean[a - 1]:.5f},{error[a - 1]:.5f}" for a in at)
        rows.append(f"{method},guarded-plain,{len(seeds)},{values},")
    return "\n".join(lines) + "\n", "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, choices=["2d", "3du", "3dt"])
    parser.add_argument("--out", default="studies/results/evaluation", help="nbv evaluate out folder (plain, --guard)")
    parser.add_argument("--views", type=int, default=100)
    args = parser.parse_args(argv)
    folder = Path(args.out) / args.dataset
    table, csv_text = compare(args.dataset, folder, views=args.views)
    (folder / f"{args.dataset}_guarded_vs_plain.md").write_text(table)
    (folder / f"{args.dataset}_guarded_vs_plain.csv").write_text(csv_text)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
