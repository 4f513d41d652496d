"""``nbv view``: render a recorded run (a bag from ``bag_record planning:=true``) to PNG and CSV."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "view"
HELP = (
    "Render a recorded run to PNG: occupied cells (top and side projections), camera poses and "
    "next best views, and a heat map of the best view gain per candidate cell (plus a CSV of it)."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--bag", required=True, type=Path, help="rosbag2 directory or .mcap file")
    parser.add_argument("--out", required=True, type=Path, help="output .png (the heat map CSV goes next to it)")
    parser.add_argument("--cell", type=float, default=0.02, help="heat-map cell size [m] (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.perception.bags import BagError
    from nbv_prob_cnn.viz.recorded_run import load_run, render_run

    try:
        run_data = load_run(args.bag)
    except (BagError, FileNotFoundError, ValueError) as exc:
        print(f"nbv view: {exc}")
        return 1
    png, csv = render_run(run_data, args.out, args.cell)
    print(
        f"{len(run_data.camera_positions)} camera pose(s), {len(run_data.next_best_views)} next best view(s), "
        f"{len(run_data.occupied)} occupied cell(s), {len(run_data.candidates)} candidate view(s); wrote {png}, {csv}"
    )
    return 0
