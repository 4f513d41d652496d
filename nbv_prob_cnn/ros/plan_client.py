"""A command-line client of ``/nbv/plan``: waits until the grid has integrated what it should
(a number of frames, or a quiet period), asks for the next best views and writes them as CSV and
a PNG. Run as its own process by the launch scripts:
``python -m nbv_prob_cnn.ros.plan_client --top-k 5 --out DIR``."""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from nbv_prob_cnn_msgs.msg import VoxelGrid
from nbv_prob_cnn_msgs.srv import PlanNextBestView

from nbv_prob_cnn.basics.grid import unknown_fraction_all
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import msg_to_grid, pose_to_arrays
from nbv_prob_cnn.ros.qos import GRID_QOS


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Plan the next best views on the integrated grid.")
    parser.add_argument("--method", default="")
    parser.add_argument("--top-k", type=int, default=5)
    parser.add_argument("--settle", type=float, default=3.0, help="seconds without a new grid before planning")
    parser.add_argument("--timeout", type=float, default=300.0)
    parser.add_argument("--out", default="out/plan")
    args = parser.parse_args(argv)
    rclpy.init()
    node = rclpy.create_node("plan_client")
    grids: list[tuple[float, VoxelGrid]] = []

    def on_grid(msg: VoxelGrid) -> None:
        # a republished grid (same stamp, integrator's republish_period_s) is not a new one
        if grids and grids[-1][1].header.stamp == msg.header.stamp:
            return
        grids.append((time.monotonic(), msg))

    node.create_subscription(VoxelGrid, names.GRID, on_grid, GRID_QOS)
    client = node.create_client(PlanNextBestView, names.PLAN)
    try:
        deadline = time.monotonic() + args.timeout
        print("[plan] waiting for the grid to settle...", flush=True)
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.2)
            if grids and time.monotonic() - grids[-1][0] >= args.settle and client.service_is_ready():
                break
        else:
            print("[plan] no settled grid and /nbv/plan within the timeout", file=sys.stderr, flush=True)
            return 1
        state, geometry = msg_to_grid(grids[-1][1])
        print(f"[plan] grid {geometry.shape}, unknown fraction {unknown_fraction_all(state):.4f}", flush=True)
        future = client.call_async(PlanNextBestView.Request(method=args.method, top_k=args.top_k))
        rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
        reply = future.result()
        if reply is None or not reply.success:
            print(f"[plan] planning failed: {reply.message if reply else 'no answer'}", file=sys.stderr, flush=True)
            return 1
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        poses = [pose_to_arrays(v.pose.pose) for v in reply.ranked]
        with open(out / "ranked_views.csv", "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["rank", "gain", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"])
            for rank, (view, (p, q)) in enumerate(zip(reply.ranked, poses, strict=True), start=1):
                writer.writerow([rank, f"{view.gain:.6g}", *(f"{v:.5f}" for v in p), *(f"{v:.6f}" for v in q)])
                print(f"[plan] #{rank}: gain {view.gain:.4f} at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f})", flush=True)
        from nbv_prob_cnn.viz.exploration import plot_views

        cells = np.array([geometry.to_index(p) for p, _ in poses])
        plot_views(state, cells, np.array([q for _, q in poses]), out / "ranked_views.png", "ranked next best views",
                   geometry=geometry)  # fmt: skip
        print(
            f"[plan] cnn {reply.time_cnn_s:.3f} s, ray casting {reply.time_raycast_s:.3f} s, views "
            f"{reply.time_views_s:.3f} s, total {reply.time_total_s:.3f} s; wrote {out / 'ranked_views.csv'}, "
            f"{out / 'ranked_views.png'}",
            flush=True,
        )
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())
