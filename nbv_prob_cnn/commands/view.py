"""``nbv view``: render a saved grid (``--grid``), an OctoMap (``--octomap``) or a recorded bag (``--bag``) to
PNG and CSV."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "view"
HELP = (
    "Render a saved grid (--grid) or a recorded bag (--bag) to PNG: projections of the grid and a heat map of "
    "the best view gain (plus a CSV of it). A bag of a planning run (bag_record planning:=true) shows its camera "
    "poses, next best views and the planner's candidate gains; a camera-only bag is fused into a grid first."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from nbv_prob_cnn.basics.datasets import DATASET_SPECS
    from nbv_prob_cnn.commands._grid_source import add_octomap_arguments
    from nbv_prob_cnn.gain import BACKENDS
    from nbv_prob_cnn.planners.methods import GAIN_METHODS
    from nbv_prob_cnn.planners.registry import DEFAULT_METHOD

    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--grid", type=Path, help="grid .npz (keys grid, origin, resolution)")
    source.add_argument("--bag", type=Path, help="rosbag2 directory or .mcap file")
    add_octomap_arguments(parser, source)
    parser.add_argument("--out", required=True, type=Path, help="output .png (the heat map CSV goes next to it)")
    parser.add_argument(
        "--method",
        default=DEFAULT_METHOD,
        choices=[m for m in GAIN_METHODS if m != "omniscient"],
        help="gain of the heat map on a grid (default: %(default)s; cnn_prob needs the data set's weights)",
    )
    parser.add_argument("--dataset", choices=sorted(DATASET_SPECS), help="sensor and rays (default: by grid shape)")
    parser.add_argument("--backend", choices=BACKENDS, default="auto", help="ray-casting backend")
    parser.add_argument(
        "--cell", type=float, default=0.02, help="planning-bag heat-map cell [m] (default: %(default)s)"
    )


def run(args: argparse.Namespace) -> int:
    if args.grid is not None or args.octomap is not None:
        from nbv_prob_cnn.commands._grid_source import read_grid

        saved = read_grid(args)
        return _render_grid(args, saved.state, saved.geometry, saved.path.name, None)
    from nbv_prob_cnn.perception.bags import bag_topics
    from nbv_prob_cnn.viz.recorded_run import PLANNING_TOPICS, load_run, render_run

    if not PLANNING_TOPICS & set(bag_topics(args.bag)):  # FileNotFoundError, BagError (a ValueError)
        return _render_camera_bag(args)
    run_data = load_run(args.bag)
    if len(run_data.candidates) == 0:
        return _render_camera_bag(args)
    png, csv = render_run(run_data, args.out, args.cell)
    print(
        f"{len(run_data.camera_positions)} camera pose(s), {len(run_data.next_best_views)} next best view(s), "
        f"{len(run_data.occupied)} occupied cell(s), {len(run_data.candidates)} candidate view(s); wrote {png}, {csv}"
    )
    return 0


def _render_camera_bag(args: argparse.Namespace) -> int:
    """A bag without a planner's candidates: fuse its depth frames (the ``nbv integrate`` defaults) and
    render that grid with the camera path."""
    import numpy as np

    from nbv_prob_cnn.basics.geometry import GridGeometry
    from nbv_prob_cnn.basics.grid import UNKNOWN
    from nbv_prob_cnn.basics.results import EmptyResultError
    from nbv_prob_cnn.perception.bags import BagError, read_frames
    from nbv_prob_cnn.perception.tsdf import DEFAULT_ORIGIN_M, DEFAULT_SHAPE, DEFAULT_VOXEL_M, TsdfIntegrator

    try:
        frames = read_frames(args.bag)
    except BagError as exc:
        raise BagError(f"--bag {args.bag}: no planning topics and no depth frames to fuse ({exc})") from None
    integrator = TsdfIntegrator(np.array(DEFAULT_ORIGIN_M), DEFAULT_SHAPE, DEFAULT_VOXEL_M)
    positions = []
    for frame in frames:
        integrator.integrate(frame.depth_m, frame.intrinsics, frame.pose_4x4)
        positions.append(frame.pose_4x4[:3, 3])
    count = len(positions)
    geometry = GridGeometry(DEFAULT_ORIGIN_M, DEFAULT_VOXEL_M, tuple(DEFAULT_SHAPE))
    state = integrator.ternary()
    if np.all(state == UNKNOWN):
        raise EmptyResultError(
            f"--bag {args.bag}: no return of its {count} depth frame(s) fell inside the box of `nbv integrate`'s "
            f"defaults ({DEFAULT_SHAPE} cells of {DEFAULT_VOXEL_M} m at {list(DEFAULT_ORIGIN_M)}); fuse it where it "
            f"lies: `nbv integrate --bag {args.bag} --bounds auto --voxel 0.04 --out grid.npz`, then "
            f"`nbv view --grid grid.npz --out {args.out}`"
        )
    print(
        f"{args.bag}: no planning topics; fused {count} depth frame(s) into the {DEFAULT_SHAPE} grid of `nbv integrate`"
    )
    cameras = np.array(positions, dtype=float).reshape(-1, 3)
    return _render_grid(args, state, geometry, f"{args.bag.name} ({count} frames fused)", cameras)


def _render_grid(args: argparse.Namespace, state, geometry, name: str, camera_positions) -> int:
    from nbv_prob_cnn.basics.datasets import DATASET_SPECS
    from nbv_prob_cnn.planners.offline import best_gain_per_origin, infer_dataset, resolution_note
    from nbv_prob_cnn.viz.saved_grid import render_saved_grid

    dataset = infer_dataset(state.shape, args.dataset)
    note = resolution_note(dataset, geometry)
    if note:
        print(note)
    origins, gains = best_gain_per_origin(state, geometry, dataset, args.method, backend=args.backend)
    stride = DATASET_SPECS[dataset].origin_stride
    title = f"{name}: grid {tuple(state.shape)} of {geometry.resolution * 100:.3g} cm cells"
    png, csv = render_saved_grid(
        state, geometry, origins, gains, args.out, title, args.method, stride, camera_positions
    )
    best = float(gains.max()) if gains.size else 0.0
    print(f"{len(origins)} candidate origin(s), best view gain {best:.4f} ({args.method}); wrote {png}, {csv}")
    if not best > 0:  # the picture is still the grid's; say why its heat map is blank
        from nbv_prob_cnn.basics.results import no_view_reason

        print(f"note: no view with a positive gain: {no_view_reason(state)}")
    return 0
