#!/usr/bin/env python3
"""Start the simulated node graph and explore a scene through the Explore action.

    sim_camera -> integrator -> nbv_planner <-> completion_server, gain_server

Every process gets localhost discovery, its own ROS_DOMAIN_ID and the Fast DDS shared-memory
profile; Ctrl-C cancels the exploration and stops every process (no orphans, and the
shared-memory files the graph created are removed). Outputs: <out>/views.csv,
<out>/explored.png, <out>/grid.npz and one log per node in <out>/logs/.

Example:  .venv/bin/python launch_scripts/explore_sim.py --views 10 --method cnn_prob
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

from nbv_prob_cnn.ros.graph import NodeGraph, ros_environment, shm_segments


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


def start_graph(graph: NodeGraph, args: argparse.Namespace) -> None:
    common = {"dataset": args.dataset}
    graph.start_node("sim_camera", "sim_camera", {**common, "seed": args.seed})
    graph.start_node("integrator", "integrator", {})
    graph.start_node("completion_server", "completion_server", common)
    graph.start_node("gain_server", "gain_server", {**common, "completion": "service"})
    graph.start_node("nbv_planner", "nbv_planner", {**common, "method": args.method, "in_process": args.in_process})


def main(argv=None) -> int:
    args = parse_args(argv)
    out = Path(args.out)
    env = ros_environment(args.domain_id)
    os.environ.update(env)  # this process is a client of the same graph
    shm_before = shm_segments()
    graph = NodeGraph(env, log_dir=out / "logs")
    interrupted = False

    def on_sigint(signum, frame):
        nonlocal interrupted
        interrupted = True
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)
    signal.signal(signal.SIGTERM, on_sigint)
    code = 1
    client = None
    try:
        print(f"[explore_sim] ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, logs in {out / 'logs'}", flush=True)
        start_graph(graph, args)
        import rclpy
        from nbv_prob_cnn_msgs.action import Explore

        from nbv_prob_cnn.ros.explore_client import ExploreClient, write_outputs

        rclpy.init()
        client = ExploreClient()
        print("[explore_sim] waiting for the graph (first grid and the Explore server)...", flush=True)
        if not client.wait_ready(120.0):
            dead = [name for name, alive in graph.alive().items() if not alive]
            print(f"[explore_sim] graph not ready after 120 s; stopped processes: {dead or 'none'}", file=sys.stderr)
            return 1
        goal = Explore.Goal(method=args.method, max_views=args.views, stop_unknown_fraction=args.stop_unknown)

        def progress(fb, elapsed):
            rate = (fb.view_index + 1) / elapsed if elapsed > 0 else 0.0
            eta = (args.views - fb.view_index - 1) / rate if rate > 0 else float("nan")
            print(
                f"[explore_sim] view {fb.view_index + 1}/{args.views}: gain {fb.gain:.4f}, "
                f"unknown {fb.unknown_fraction:.4f}, {elapsed:.1f} s elapsed, ETA {eta:.0f} s",
                flush=True,
            )

        started = time.monotonic()
        result = client.explore(goal, args.timeout, progress)
        written = write_outputs(client, result, out, f"{args.dataset} seed {args.seed}, {args.method}")
        print(
            f"[explore_sim] done: {result.views} views in {time.monotonic() - started:.1f} s, final unknown fraction "
            f"{result.final_unknown_fraction:.4f}, stopped: {result.reason_stopped}; wrote "
            + ", ".join(str(p) for p in written),
            flush=True,
        )
        code = 0 if result.views > 0 else 1
    except KeyboardInterrupt:
        print("\n[explore_sim] interrupted: cancelling and stopping the graph", flush=True)
        if client is not None:
            try:
                client.cancel()
            except Exception:  # noqa: BLE001 - best effort while shutting down
                pass
        code = 130
    finally:
        if client is not None:
            client.destroy()
        try:
            import rclpy

            rclpy.try_shutdown()
        except ImportError:
            pass
        codes = graph.stop()
        leaked = shm_segments() - shm_before
        for name in leaked:  # files of our (now stopped) processes only
            try:
                os.unlink(f"/dev/shm/{name}")
            except OSError:
                pass
        print(
            f"[explore_sim] stopped {len(codes)} processes; removed {len(leaked)} stale shared-memory files", flush=True
        )
    return code if not interrupted else 130


if __name__ == "__main__":
    raise SystemExit(main())
