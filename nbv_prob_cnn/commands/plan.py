"""``nbv plan --grid grid.npz`` (or ``--octomap map.bt``): the best next views on a saved grid, without ROS."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

NAME = "plan"
HELP = (
    "Plan the best next views on a saved grid (nbv integrate, the integrator's save service, the main job's "
    "grid.npz) without ROS: poses in metres with quaternions, as CSV and PNG."
)

#: The search's stages in the closing line: key of ``ViewChoice.times``, name printed.
STAGES = (("cnn", "CNN"), ("raycast", "ray casting"), ("views", "views"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from nbv_prob_cnn.basics.datasets import DATASET_SPECS
    from nbv_prob_cnn.basics.modes import CNN_PRECISIONS
    from nbv_prob_cnn.commands._grid_source import add_octomap_arguments
    from nbv_prob_cnn.gain import BACKENDS
    from nbv_prob_cnn.planners import METHODS
    from nbv_prob_cnn.planners.registry import DEFAULT_METHOD

    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--grid", type=Path, help="grid .npz (keys grid, origin, resolution)")
    add_octomap_arguments(parser, source)
    parser.add_argument(
        "--method",
        default=DEFAULT_METHOD,
        choices=[m for m, s in METHODS.items() if not s.needs_ground_truth],
        help="next-best-view method (default: %(default)s)",
    )
    parser.add_argument(
        "--dataset",
        choices=sorted(DATASET_SPECS),
        help="sensor, rays and weights to use (default: by the grid's shape; 3dt for other 3D grids)",
    )
    parser.add_argument(
        "--workspace",
        nargs="+",
        type=float,
        metavar="M",
        help="only camera positions in this box: XMIN YMIN [ZMIN] XMAX YMAX [ZMAX] in metres",
    )
    parser.add_argument("--top-k", type=int, default=10, help="number of views (default: %(default)s)")
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("plan"),
        help="output prefix: writes PREFIX.csv and PREFIX.png (default: %(default)s)",
    )
    parser.add_argument("--backend", choices=BACKENDS, default="auto", help="ray-casting backend")
    parser.add_argument("--seed", type=int, default=0, help="random seed (random, cnn_prob_d)")
    parser.add_argument(
        "--cnn-window",
        type=int,
        metavar="CELLS",
        help="complete only the candidates' box grown by this margin (48 = 3DT's receptive field), p0 outside "
        "(default: every cell the rays read)",
    )
    parser.add_argument(
        "--cnn-precision",
        choices=CNN_PRECISIONS,
        default="float32",
        help="the CNN's arithmetic: float32 (as trained) or bfloat16 (faster on CPUs with AVX512-BF16 or AMX)",
    )


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.basics.grid import EMPTY
    from nbv_prob_cnn.basics.peak_memory import peak_rss_mb
    from nbv_prob_cnn.basics.results import EmptyResultError, no_view_reason
    from nbv_prob_cnn.commands._grid_source import read_grid, source_text
    from nbv_prob_cnn.planners.offline import infer_dataset, plan_views, resolution_note, write_views_csv
    from nbv_prob_cnn.viz.exploration import plot_views

    saved = read_grid(args)
    dataset = infer_dataset(saved.state.shape, args.dataset)
    note = resolution_note(dataset, saved.geometry)
    if note:
        print(note)
    if not (saved.state == EMPTY).any():  # before the CNN: no cell to put a camera in
        raise EmptyResultError(f"{source_text(args)}: no view: {no_view_reason(saved.state)}")
    times: dict[str, float] = {}
    start = time.perf_counter()
    poses = plan_views(
        saved.state, saved.geometry, dataset, args.method, args.top_k, args.workspace, args.backend, args.seed, times,
        args.cnn_window, args.cnn_precision,
    )  # fmt: skip
    plan_s = time.perf_counter() - start
    if not poses:
        raise EmptyResultError(f"{source_text(args)}: no view with a positive gain: {no_view_reason(saved.state)}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    csv_path = write_views_csv(poses, args.out.with_suffix(".csv"))
    png = args.out.with_suffix(".png")
    import numpy as np

    cells = np.array([p.cell for p in poses], dtype=float).reshape(-1, saved.state.ndim)
    quats = np.array([p.quaternion_xyzw for p in poses]).reshape(-1, 4)
    title = f"{saved.path.name}: the {len(poses)} best views of {args.method} ({dataset} sensor)"
    plot_views(saved.state, cells, quats, png, title, geometry=saved.geometry)
    for rank, pose in enumerate(poses, start=1):
        x, y, z = pose.position_m
        qx, qy, qz, qw = pose.quaternion_xyzw
        print(
            f"#{rank}: gain {pose.gain:.4f} at ({x:.3f}, {y:.3f}, {z:.3f}) m, "
            f"quaternion (x, y, z, w) ({qx:.4f}, {qy:.4f}, {qz:.4f}, {qw:.4f}), cell {list(pose.cell)}"
        )
    print(f"wrote {csv_path}, {png}")
    stages = ", ".join(f"{name} {times.get(key, 0.0):.2f} s" for key, name in STAGES)
    print(f"plan {plan_s:.2f} s ({stages}), peak RSS {peak_rss_mb():.0f} MB")
    return 0
