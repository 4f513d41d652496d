"""``nbv gain-study``: does the gain that ``/nbv/evaluate_views`` predicts rank what a recorded camera
then saw? (:mod:`nbv_prob_cnn.exploration.gain_study`,
docs/evaluation.md#does-the-gain-predict-what-a-real-camera-sees)"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

NAME = "gain-study"
HELP = (
    "Rank the gains /nbv/evaluate_views predicts for recorded camera poses against the cells each frame then "
    "revealed (Spearman rho per anchor and pooled, bootstrap intervals; CSV and PNG)."
)
TABLE_HEADER = (
    "| against | variant | method | pooled rho [95 %] | within-anchor rho [95 %] | anchors | rays in frustum |"
)
#: The default variants: sensor model and sampling, crossed, on the service's rays (across each pose's image;
#: n_rays is read only with rays_across=0, e.g. --vary rays_across=0,32 --vary n_rays=4,8,16).
DEFAULT_VARY = ("sensor=paper,returns", "sampling=rounded,exact")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--bag", required=True, type=Path, help="rosbag2 of posed depth frames (nbv import-rgbd)")
    parser.add_argument("--out", required=True, type=Path, help="folder for poses.csv, rho.csv, rho.png, summary.md")
    parser.add_argument("--methods", default="ig,prob_ig,cnn_prob", help="gain methods, comma-separated "
                        "(default: %(default)s)")  # fmt: skip
    parser.add_argument("--voxel", type=float, default=0.04, help="cell edge, m (default: %(default)s)")
    parser.add_argument("--anchors", type=int, default=8, help="anchor frames K (default: %(default)s)")
    parser.add_argument("--next", type=int, default=10, dest="next_poses", help="recorded poses scored after each "
                        "anchor, M (default: %(default)s)")  # fmt: skip
    parser.add_argument(
        "--vary", action="append", metavar="KEY=V1,V2,...",
        help="scoring settings to vary from the service's defaults, crossed; KEY: n_rays, sensor (paper, returns), "
        "sampling (rounded, exact), rays_across (0 = the view search's rays; N = N rays across the pose's image), "
        "max_range_m (0 = the data set's); n_rays is read only where rays_across is 0 (the service casts rays "
        f"across the image by default); default: {' '.join(DEFAULT_VARY)}",
    )  # fmt: skip
    parser.add_argument("--depth-max", type=float, default=3.0, help="fusion: returns beyond this depth are "
                        "ignored, m (default: %(default)s)")  # fmt: skip
    parser.add_argument("--dataset", default="", help="the service's data set (sensor, rays, CNN weights; default: "
                        "gain_server's)")  # fmt: skip
    parser.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.exploration.gain_study import BASELINE, run_gain_study
    from nbv_prob_cnn.exploration.gain_study_summary import rho_line, summarise, write_csv
    from nbv_prob_cnn.exploration.scoring_variants import cross_variants
    from nbv_prob_cnn.perception.realized_gain import Fusion
    from nbv_prob_cnn.planners.requests import gain_method
    from nbv_prob_cnn.ros.evaluate_views_setup import service_scoring
    from nbv_prob_cnn.viz.gain_study import plot_gain_study

    if not args.bag.exists():
        raise FileNotFoundError(f"--bag: no such bag {args.bag}")
    if args.resamples < 1:
        raise ValueError(f"--resamples: expected at least 1, got {args.resamples}")
    names = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not names:
        raise ValueError("--methods: name at least one method")
    try:
        methods = [gain_method(name, "") for name in names]
    except ValueError as exc:
        raise ValueError(f"--methods: {exc}") from None
    fusion = Fusion(args.voxel, args.depth_max)
    default, context_for = service_scoring(args.dataset)
    variants = cross_variants(default, args.vary if args.vary else DEFAULT_VARY)
    progress = not args.no_progress and sys.stderr.isatty()
    study = run_gain_study(args.bag, fusion, methods, variants, context_for, args.anchors, args.next_poses, progress)
    summary = summarise(study, args.resamples, seed=args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(args.out / "poses.csv", study.rows)
    write_csv(args.out / "rho.csv", summary)
    revealed = [r for r in summary if r.target == "revealed"]  # the picture: the cells revealed
    plot_gain_study(study, revealed, default.label, args.out / "rho.png")
    command = "nbv gain-study " + " ".join(shlex.quote(a) for a in sys.argv[2:])
    lines = _report(study, summary, default.label, command)
    (args.out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[lines.index(TABLE_HEADER) :]))
    print(rho_line(summary, BASELINE[1], "within", "surface"))
    print(rho_line(summary, default.label, "within", "surface"))
    print(rho_line(summary, default.label, "pooled", "surface"))
    print(rho_line(summary, BASELINE[1], "within"))
    print(rho_line(summary, BASELINE[1], "pooled"))
    print(rho_line(summary, default.label, "within"))
    print(rho_line(summary, default.label, "pooled"))
    return 0


def _report(study, summary, default_label: str, command: str) -> list[str]:
    """summary.md: the command, the box, the anchors and one line per variant (pooled and within ρ)."""
    g = study.geometry
    size = " x ".join(f"{n * g.resolution:.2f}" for n in g.shape)
    lines = [
        "# nbv gain-study", "", f"    {command}", "",
        f"- box: {tuple(g.shape)} cells of {g.resolution:g} m ({size} m), origin {[round(v, 3) for v in g.origin]}",
        f"- frames: {study.frames}; anchors (frame index: unknown share): "
        + ", ".join(f"{a}: {study.unknown_share[a]:.0%}" for a in study.anchors),
        f"- the service's defaults: {default_label}", "",
        TABLE_HEADER,
        "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    by_key = {(r.target, r.method, r.variant, r.scope): r for r in summary if r.scope != "anchor"}
    for (target, method, variant, scope), row in by_key.items():
        if scope != "pooled":
            continue
        within = by_key[(target, method, variant, "within")]
        against = "cells revealed" if target == "revealed" else "surface seen"
        cells = (against, variant, method, row.text(), within.text(), row.anchors, f"{row.mean_rays_in_frustum:.1f}")
        lines.append("| " + " | ".join(map(str, cells)) + " |")
    return lines
