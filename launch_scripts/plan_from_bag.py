#!/usr/bin/env python3
"""Start the node graph on a recorded bag and plan the next best views on what it saw.

    bag_replay -> integrator -> nbv_planner <-> completion_server, gain_server
                                     ^-- plan_client (waits for the grid to settle, calls /nbv/plan)

The integrator poses the images as the bag does: by ``/camera/pose`` (``pose_source:=topic``, the
simulated bags) or, in a bag without it, by ``/tf`` (``pose_source:=tf``: a robot's recording,
``nbv import-rgbd``'s bags). Its grid is the data set's box (``--dataset``, ``--voxel``,
``--origin``, ``--shape``), or with ``--bounds auto`` the box of every cell the recording observes
at ``--voxel`` and every camera position (found offline first, as ``nbv gain-study`` does).

Same process handling as explore_sim.py (own ROS_DOMAIN_ID, localhost discovery, shared-memory
profile, clean Ctrl-C, a node's exit reported with its last error line and log: then the rest stop).
``bag_replay`` ends by itself after the last message. Outputs: <out>/ranked_views.csv,
<out>/ranked_views.png, node logs.

Exit status: 0 planned, 1 the planning failed, 2 a bad argument or bag, 4 a node exited,
124 ``--timeout`` passed, 130 Ctrl-C.

Examples:
    .venv/bin/python launch_scripts/plan_from_bag.py --bag bags/3dt_seed1000_sample
    nbv import-rgbd --format 7scenes ../shared/data/rgbd/7scenes_redkitchen --max-frames 20 --out kitchen20
    .venv/bin/python launch_scripts/plan_from_bag.py --bag kitchen20 --bounds auto --voxel 0.04 --method prob_ig
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nbv_prob_cnn.basics.camera import dataset_defaults
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.perception.bags import BagError, bag_pose_source, read_frames
from nbv_prob_cnn.perception.realized_gain import Fusion, recording_box
from nbv_prob_cnn.planners.registry import DEFAULT_METHOD, ros_method_names
from nbv_prob_cnn.ros.graph import NodeGraph, ros_environment, run_graph

#: ``pose_source:=tf``: how long the integrator holds an image for its transform [s] (the node's
#: default is 1 s; a replay is paced, so a longer wait costs nothing and rides out a slow match of /tf).
TF_POSE_TIMEOUT_S = 5.0


def grid_box(args: argparse.Namespace) -> GridGeometry:
    """The integrator's box: the data set's (or ``--origin``/``--shape``) at ``--voxel``, or with
    ``--bounds auto`` the recording's (:func:`~nbv_prob_cnn.perception.realized_gain.recording_box`)."""
    defaults = dataset_defaults(args.dataset)
    voxel = args.voxel if args.voxel is not None else defaults.resolution_m
    if args.bounds == "auto":
        return recording_box(read_frames(args.bag), Fusion(voxel, args.depth_max))
    origin = tuple(args.origin) if args.origin is not None else (0.0, 0.0, 0.0)
    shape = tuple(args.shape) if args.shape is not None else tuple(defaults.shape)
    return GridGeometry(origin, voxel, shape)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bag", default="bags/3dt_seed1000_sample", help="rosbag2 directory or .mcap")
    parser.add_argument("--dataset", default="3dt", choices=["3du", "3dt"], help="grid box and CNN weights")
    methods = ros_method_names()
    parser.add_argument(
        "--method", default=DEFAULT_METHOD, choices=methods, metavar="METHOD",
        help=f"the planner's method (default {DEFAULT_METHOD}): " + ", ".join(methods),
    )  # fmt: skip
    parser.add_argument("--top-k", type=int, default=5)
    parser.add_argument("--rate", type=float, default=5.0, help="replay speed factor")
    parser.add_argument(
        "--bounds", choices=("box", "auto"), default="box",
        help="box: the data set's box (or --origin/--shape); auto: the recording's (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument("--voxel", type=float, help="cell edge in m (default: the data set's)")
    parser.add_argument("--origin", nargs=3, type=float, metavar=("X", "Y", "Z"), help="box corner (default: 0 0 0)")
    parser.add_argument("--shape", nargs=3, type=int, metavar=("NX", "NY", "NZ"), help="box size in cells")
    parser.add_argument("--depth-max", type=float, default=3.0, help="ignore returns beyond this depth, m")
    parser.add_argument("--out", default="out/plan_from_bag")
    parser.add_argument("--domain-id", type=int)
    parser.add_argument(
        "--timeout", type=float, default=3600.0,
        help="seconds for the whole run, the start of the graph included (default 3600; then exit status 124)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    args.bag = Path(args.bag).resolve()
    if not args.bag.exists():
        print(f"plan_from_bag: no such bag {str(args.bag)!r}", file=sys.stderr)
        return 2
    try:
        pose_source = bag_pose_source(args.bag)
        box = grid_box(args)
    except (BagError, ValueError) as exc:
        print(f"plan_from_bag: {exc}", file=sys.stderr)
        return 2
    poses = {"topic": "/camera/pose", "tf": "/tf"}[pose_source]
    print(
        f"[plan_from_bag] poses from {poses} (integrator pose_source:={pose_source}); grid {box.shape} at "
        f"{box.resolution:g} m, origin {[round(v, 6) for v in box.origin]}",
        flush=True,
    )
    common = {"dataset": args.dataset}

    def start_nodes(graph: NodeGraph) -> None:
        integrator = {
            "origin": [float(v) for v in box.origin], "shape": [int(v) for v in box.shape],
            "voxel_size": float(box.resolution), "depth_max_m": args.depth_max, "pose_source": pose_source,
        }  # fmt: skip
        if pose_source == "tf":
            integrator["pose_timeout_s"] = TF_POSE_TIMEOUT_S
        # the defaults lose no frame (bag_replay waits for the integrator's subscriptions and paces
        # each frame by its diagnostics)
        graph.start_node("integrator", "integrator", integrator)
        graph.start_node("completion_server", "completion_server", common)
        graph.start_node("gain_server", "gain_server", common)
        graph.start_node("nbv_planner", "nbv_planner", {**common, "method": args.method})
        # a longer wait than the default 30 s: four nodes load at once
        replay = {"bag": str(args.bag), "rate": args.rate, "wait_timeout_s": 60.0}
        graph.start_node("bag_replay", "bag_replay", replay, may_exit=True)  # done after the last message

    client = [sys.executable, "-m", "nbv_prob_cnn.ros.plan_client", "--method", args.method,
              "--top-k", str(args.top_k), "--out", args.out]  # fmt: skip
    env = ros_environment(args.domain_id)
    return run_graph(start_nodes, client, env, Path(args.out) / "logs", "plan_from_bag", timeout_s=args.timeout)


if __name__ == "__main__":
    raise SystemExit(main())
