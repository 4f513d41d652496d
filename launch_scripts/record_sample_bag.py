#!/usr/bin/env python3
"""Create the shipped sample depth-camera bag ``bags/3dt_seed1000_sample`` (no ROS needed).

Renders frames of the 3DT world of a seed with the simulated depth camera (open3d ray casting)
from poses on a ring around the table and writes them with :class:`BagWriter` as a rosbag2
directory (mcap storage) with the three camera topics of docs/method.md#node-graph.

Usage (from the repository root)::

    .venv/bin/python launch_scripts/record_sample_bag.py            # the shipped bag
    .venv/bin/python launch_scripts/record_sample_bag.py --out /tmp/bag --frames 40 --width 640 --height 480

The output is deterministic for a given world generator version: same poses, same stamps
(5 Hz from 2025-01-01T00:00:00Z), same depth values.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
START_NS = 1_735_689_600 * 1_000_000_000  # 2025-01-01T00:00:00Z
PERIOD_NS = 200_000_000  # 5 Hz
#: ring of camera positions around the table centre of the 3DT box (1.48 x 1.48 m), heights above the table top
CENTRE_XY = (0.742, 0.742)
RADIUS_M = 0.55
HEIGHTS_ABOVE_TABLE_M = (0.40, 0.57)
TARGET_ABOVE_TABLE_M = 0.05


def ring_poses(frames: int, table_height_m: float) -> list[np.ndarray]:
    """``world_from_optical`` poses: one turn around the table, alternating two heights, looking at
    points near the table centre (slightly jittered so views are not all centred alike)."""
    from nbv_prob_cnn.basics.camera import look_rotation

    poses = []
    for i in range(frames):
        angle = 2.0 * math.pi * i / frames - math.pi / 2  # start in front (-y side)
        position = np.array(
            [
                CENTRE_XY[0] + RADIUS_M * math.cos(angle),
                CENTRE_XY[1] + RADIUS_M * math.sin(angle),
                table_height_m + HEIGHTS_ABOVE_TABLE_M[i % 2],
            ]
        )
        target = np.array(
            [
                CENTRE_XY[0] + 0.12 * math.cos(3 * angle),
                CENTRE_XY[1] + 0.12 * math.sin(3 * angle),
                table_height_m + TARGET_ABOVE_TABLE_M,
            ]
        )
        pose = np.eye(4)
        pose[:3, :3] = look_rotation(target - position)
        pose[:3, 3] = position
        poses.append(pose)
    return poses


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=REPO / "bags" / "3dt_seed1000_sample", help="bag directory")
    parser.add_argument("--seed", type=int, default=1000, help="3DT world seed (default: %(default)s)")
    parser.add_argument("--frames", type=int, default=30, help="number of frames (default: %(default)s)")
    parser.add_argument("--width", type=int, default=320, help="image width px (default: %(default)s)")
    parser.add_argument("--height", type=int, default=240, help="image height px (default: %(default)s)")
    parser.add_argument("--hfov-deg", type=float, default=60.0, help="horizontal FOV (default: %(default)s)")
    parser.add_argument("--encoding", choices=("16UC1", "32FC1"), default="16UC1", help="(default: %(default)s)")
    parser.add_argument("--force", action="store_true", help="replace an existing bag at --out")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be positive")

    from nbv_prob_cnn.perception import BagWriter, DepthCamera, Intrinsics
    from nbv_prob_cnn.worlds import GENERATOR_VERSION, load_or_generate

    if args.out.exists():
        if not args.force:
            print(f"{args.out}: exists already (use --force to replace it)", file=sys.stderr)
            return 1
        shutil.rmtree(args.out)
    world = load_or_generate("3dt", args.seed)
    camera = DepthCamera(world.triangle_meshes(), Intrinsics.from_hfov(args.width, args.height, args.hfov_deg))
    valid = []
    with BagWriter(args.out) as bag:
        for i, pose in enumerate(ring_poses(args.frames, float(world.table["height_m"]))):
            depth = camera.render(pose)
            valid.append(float(np.mean(depth > 0)))
            bag.write_frame(START_NS + i * PERIOD_NS, depth, camera.intrinsics, pose, encoding=args.encoding)
    size = sum(p.stat().st_size for p in args.out.rglob("*") if p.is_file())
    print(
        f"{args.out}: {args.frames} frames {args.width}x{args.height} {args.encoding} of 3dt world seed {args.seed} "
        f"(generator v{GENERATOR_VERSION}), {np.mean(valid):.0%} pixels with a return, {size / 1e6:.2f} MB"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
