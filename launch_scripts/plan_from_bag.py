#!/usr/bin/env python3
"""Start the node graph on a recorded bag and plan the next best views on what it saw.

    bag_replay -> integrator -> nbv_planner <-> completion_server, gain_server
                                     ^-- plan_client (waits for the grid to settle, calls /nbv/plan)

Same process handling as explore_sim.py (own ROS_DOMAIN_ID, localhost discovery, shared-memory
profile, clean Ctrl-C). Outputs: <out>/ranked_views.csv, <out>/ranked_views.png, node logs.

Example:  .venv/bin/python launch_scripts/plan_from_bag.py --bag bags/3dt_seed1000_sample
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nbv_prob_cnn.basics.camera import dataset_defaults
from nbv_prob_cnn.ros.graph import NodeGraph, ros_environment, run_graph


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bag", default="bags/3dt_seed1000_sample", help="rosbag2 directory or .mcap")
    parser.add_argument("--dataset", default="3dt", choices=["3du", "3dt"], help="grid box and CNN weights")
    parser.add_argument("--method", default="cnn_prob")
    parser.add_argument("--top-k", type=int, default=5)
    parser.add_argument("--rate", type=float, default=5.0, help="replay speed factor")
    parser.add_argument("--out", default="out/plan_from_bag")
    parser.add_argument("--domain-id", type=int)
    args = parser.parse_args(argv)
    if not Path(args.bag).exists():
        print(f"plan_from_bag: no such bag {args.bag!r}", file=sys.stderr)
        return 2
    defaults = dataset_defaults(args.dataset)
    common = {"dataset": args.dataset}

    def start_nodes(graph: NodeGraph) -> None:
        box = {"origin": [0.0, 0.0, 0.0], "shape": list(defaults.shape), "voxel_size": defaults.resolution_m}
        # the bag carries its poses on /camera/pose; the defaults lose no frame (bag_replay waits
        # for the integrator's subscriptions and paces each frame by its diagnostics)
        graph.start_node("integrator", "integrator", {**box, "pose_source": "topic"})
        graph.start_node("completion_server", "completion_server", common)
        graph.start_node("gain_server", "gain_server", common)
        graph.start_node("nbv_planner", "nbv_planner", {**common, "method": args.method})
        # a longer wait than the default 30 s: four nodes load at once
        replay = {"bag": str(Path(args.bag).resolve()), "rate": args.rate, "wait_timeout_s": 60.0}
        graph.start_node("bag_replay", "bag_replay", replay)

    client = [sys.executable, "-m", "nbv_prob_cnn.ros.plan_client", "--method", args.method,
              "--top-k", str(args.top_k), "--out", args.out]  # fmt: skip
    return run_graph(start_nodes, client, ros_environment(args.domain_id), Path(args.out) / "logs", "plan_from_bag")


if __name__ == "__main__":
    raise SystemExit(main())
