#!/usr/bin/env python3
"""Start the simulated node graph and explore a scene through the Explore action.

    sim_camera -> integrator -> nbv_planner <-> completion_server, gain_server
                                     ^-- explore_client (sends the Explore goal, records the run)

Every process gets localhost discovery, its own ROS_DOMAIN_ID and the Fast DDS shared-memory
profile. Ctrl-C cancels the exploration and stops every process (no orphans), then removes the
shared-memory files the graph left behind. Outputs: <out>/views.csv, <out>/explored.png,
<out>/grid.npz and one log per node in <out>/logs/.

Example:  .venv/bin/python launch_scripts/explore_sim.py --views 10 --method cnn_prob
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nbv_prob_cnn.camera import dataset_defaults
from nbv_prob_cnn.ros.graph import NodeGraph, ros_environment, run_graph


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="3dt", choices=["3du", "3dt"], help="scene type (default 3dt)")
    parser.add_argument("--seed", type=int, default=1000, help="scene seed (default 1000, a held-out scene)")
    parser.add_argument("--views", type=int, default=10, help="views to plan (default 10)")
    parser.add_argument("--method", default="cnn_prob", help="cnn_prob, cnn_prob_d, prob_ig or ig")
    parser.add_argument("--in-process", action="store_true", help="planner completes and ray-casts itself")
    parser.add_argument("--stop-unknown", type=float, default=0.0, help="stop at this unknown fraction")
    parser.add_argument("--out", default="out/explore_sim", help="output directory")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: derived from the pid)")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds for the whole exploration")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    out = Path(args.out)
    defaults = dataset_defaults(args.dataset)
    common = {"dataset": args.dataset}

    def start_nodes(graph: NodeGraph) -> None:
        graph.start_node("sim_camera", "sim_camera", {**common, "seed": args.seed})
        box = {"origin": [0.0, 0.0, 0.0], "shape": list(defaults.shape), "voxel_size": defaults.resolution_m}
        graph.start_node("integrator", "integrator", box)
        graph.start_node("completion_server", "completion_server", common)
        graph.start_node("gain_server", "gain_server", {**common, "completion": "service"})
        planner = {**common, "method": args.method, "in_process": args.in_process}
        graph.start_node("nbv_planner", "nbv_planner", planner)

    client = [
        sys.executable, "-m", "nbv_prob_cnn.ros.explore_client", "--views", str(args.views),
        "--method", args.method, "--stop-unknown", str(args.stop_unknown), "--out", str(out),
        "--title", f"{args.dataset} seed {args.seed}, {args.method}", "--timeout", str(args.timeout),
    ]  # fmt: skip
    return run_graph(start_nodes, client, ros_environment(args.domain_id), out / "logs", "explore_sim")


if __name__ == "__main__":
    raise SystemExit(main())
