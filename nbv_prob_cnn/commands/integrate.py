"""``nbv integrate``: build a ternary grid offline from a depth-camera rosbag2 (TSDF fusion); each image
is posed by ``/camera/pose`` or, in a bag without it, by ``/tf`` (+ ``/tf_static``) at its stamp
(:func:`~nbv_prob_cnn.perception.bags.read_frames`)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

NAME = "integrate"
HELP = "Fuse the posed depth images of a rosbag2 (mcap) into a ternary grid (.npz)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the command-line options."""
    from nbv_prob_cnn.perception.messages import WORLD_FRAME
    from nbv_prob_cnn.perception.tsdf import (
        DEFAULT_EMPTY_MARGIN_VOXELS,
        DEFAULT_ORIGIN_M,
        DEFAULT_SHAPE,
        DEFAULT_TRUNC_VOXELS,
        DEFAULT_VOXEL_M,
        FUSION_MODES,
    )

    parser.add_argument("--bag", required=True, type=Path, help="rosbag2 directory or .mcap file")
    parser.add_argument(
        "--fixed-frame",
        default=WORLD_FRAME,
        help="a bag posed by /tf: the frame each image's pose is looked up in (default: %(default)s)",
    )
    parser.add_argument("--out", required=True, type=Path, help="output grid .npz (keys grid, origin, resolution)")
    parser.add_argument(
        "--origin",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        default=list(DEFAULT_ORIGIN_M),
        help="world coordinates (m) of the corner of cell 0; with --bounds auto a corner of the cell lattice "
        "(default: %(default)s)",
    )
    parser.add_argument(
        "--shape",
        nargs=3,
        type=int,
        metavar=("NX", "NY", "NZ"),
        default=list(DEFAULT_SHAPE),
        help="grid size in cells with --bounds box (default: 3DT %(default)s)",
    )
    parser.add_argument(
        "--bounds",
        choices=("box", "auto"),
        default="box",
        help="box: the --origin/--shape box; auto: the box of every cell the recording observed (the grid grows "
        "as it is seen; sparse fusion) (default: %(default)s)",
    )
    parser.add_argument(
        "--fusion",
        choices=FUSION_MODES,
        default="sparse",
        help="sparse: per frame only the blocks its rays cross; dense: every block of the box (same cells) "
        "(default: %(default)s)",
    )
    parser.add_argument("--voxel", type=float, default=DEFAULT_VOXEL_M, help="cell edge in m (default: %(default)s)")
    parser.add_argument(
        "--trunc-voxels",
        type=float,
        default=DEFAULT_TRUNC_VOXELS,
        help="TSDF truncation in voxels (default: %(default)s)",
    )
    parser.add_argument(
        "--empty-margin-voxels",
        type=float,
        default=DEFAULT_EMPTY_MARGIN_VOXELS,
        help="cells more than this many voxels in front of a surface are empty (default: %(default)s)",
    )
    parser.add_argument("--depth-max", type=float, default=3.0, help="ignore returns beyond this depth, m (default: 3)")
    parser.add_argument("--refine-pose-icp", action="store_true", help="refine each pose by frame-to-model odometry")
    parser.add_argument(
        "--mesh", type=Path, help="also write the surface (marching cubes of the TSDF, world metres) as a PLY mesh"
    )
    parser.add_argument("--cloud", type=Path, help="also write the occupied cell centres (world metres) as a PLY cloud")
    parser.add_argument("--mesh-png", type=Path, help="also draw the surface (decimated, coloured by height) to a PNG")
    parser.add_argument(
        "--force", action="store_true", help="overwrite --out (and --mesh, --cloud, --mesh-png) when they exist"
    )


def run(args: argparse.Namespace) -> int:
    """Integrate every frame of the bag and write the grid."""
    from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN
    from nbv_prob_cnn.basics.results import EmptyResultError
    from nbv_prob_cnn.perception.bags import TOPIC_POSE, bag_pose_source, read_frames
    from nbv_prob_cnn.perception.surfaces import occupied_centres, render_mesh_png, write_ply
    from nbv_prob_cnn.perception.tsdf import TsdfIntegrator, save_grid

    if any(s <= 0 for s in args.shape):
        raise ValueError(f"--shape: sizes must be positive, got {args.shape}")
    if not args.voxel > 0:
        raise ValueError(f"--voxel: must be positive, got {args.voxel}")
    for option, path in (("--mesh", args.mesh), ("--cloud", args.cloud)):
        if path is not None and path.suffix.lower() != ".ply":
            raise ValueError(f"{option}: expected a .ply file, got {path}")
    if args.bounds == "auto" and args.fusion == "dense":
        raise ValueError("--bounds auto needs --fusion sparse (dense fusion updates a fixed box)")
    outputs = (("--out", args.out), ("--mesh", args.mesh), ("--cloud", args.cloud), ("--mesh-png", args.mesh_png))
    for option, path in outputs:
        if path is not None and path.exists() and not args.force:
            raise ValueError(
                f"{option} {path} exists; nothing was written (give another path, or --force to overwrite)"
            )
    t0 = time.perf_counter()
    integrator = TsdfIntegrator(
        origin_m=np.array(args.origin, dtype=np.float64),
        shape_cells=tuple(args.shape) if args.bounds == "box" else None,
        voxel_size_m=args.voxel,
        trunc_voxels=args.trunc_voxels,
        empty_margin_voxels=args.empty_margin_voxels,
        refine_pose_icp=args.refine_pose_icp,
        fusion=args.fusion,
    )
    poses = TOPIC_POSE if bag_pose_source(args.bag) == "topic" else f"/tf in {args.fixed_frame!r}"
    # validates the whole bag first (BagError is a ValueError)
    frames = read_frames(args.bag, fixed_frame=args.fixed_frame)
    t_read = time.perf_counter()
    for frame in frames:
        integrator.integrate(frame.depth_m, frame.intrinsics, frame.pose_4x4, depth_max=args.depth_max)
    t_extract = time.perf_counter()
    if integrator.stats.frames == 0:
        raise ValueError(
            f"--bag {args.bag}: no depth image could be posed (poses from {poses}), nothing was fused and no grid "
            "was written; the warnings above name the skipped messages"
        )
    origin, shape = integrator.grid_box()
    grid = integrator.ternary()
    if grid.max() == UNKNOWN:  # no return and no free space inside the box
        where = "the --bounds box" if args.bounds == "box" else "the grid"
        raise EmptyResultError(
            f"no return of the {integrator.stats.frames} frame(s) fell inside {where} (origin "
            f"{[round(float(v), 3) for v in origin]} m, {tuple(shape)} cells of {args.voxel} m), so every cell is "
            f"unknown and no grid was written: fuse where the recording lies with `--bounds auto`, or give "
            f"--origin/--shape around it"
        )
    save_grid(args.out, grid, origin, args.voxel, frames=integrator.stats.frames)
    t_end = time.perf_counter()
    labels = (("unknown", UNKNOWN), ("empty", EMPTY), ("occupied", OCCUPIED))
    counts = {name: int(np.count_nonzero(grid == value)) for name, value in labels}
    n = integrator.stats.frames
    print(f"frames read: {n} (poses from {poses})")
    print(f"grid {tuple(grid.shape)} voxel {args.voxel} m origin {[round(float(v), 6) for v in origin]} -> {args.out}")
    print(f"unknown: {counts['unknown']}  empty: {counts['empty']}  occupied: {counts['occupied']}")
    print(
        f"time: {t_end - t0:.2f} s (set-up + bag validation {t_read - t0:.2f} s, "
        f"integrate {integrator.stats.seconds:.2f} s, extract+save {t_end - t_extract:.2f} s)"
    )
    if args.mesh is not None or args.mesh_png is not None:
        vertices, triangles = integrator.mesh()
        if args.mesh is not None:
            write_ply(args.mesh, vertices, triangles)
            print(f"mesh: {len(vertices)} vertices, {len(triangles)} triangles -> {args.mesh}")
        if args.mesh_png is not None:
            title = f"{args.bag.name}: {n} frames at {args.voxel:g} m"
            render_mesh_png(args.mesh_png, vertices, triangles, title=title)
            print(f"mesh picture -> {args.mesh_png}")
    if args.cloud is not None:
        points = occupied_centres(grid, origin, args.voxel)
        write_ply(args.cloud, points)
        print(f"cloud: {len(points)} occupied cell centres -> {args.cloud}")
    print(fusion_line(n, integrator.stats.seconds, shape, args.voxel))
    return 0


def fusion_line(frames: int, seconds: float, shape: tuple[int, int, int], voxel_m: float) -> str:
    """``fused N frames in S s (F frames/s), grid NX x NY x NZ at V m, peak RSS M MB`` (this process)."""
    from nbv_prob_cnn.basics.peak_memory import peak_rss_mb

    rate = frames / seconds if seconds > 0 else float("nan")
    peak_mb = peak_rss_mb()
    nx, ny, nz = shape
    return (
        f"fused {frames} frames in {seconds:.2f} s ({rate:.1f} frames/s), grid {nx} x {ny} x {nz} at {voxel_m:g} m, "
        f"peak RSS {peak_mb:.0f} MB"
    )
