"""``nbv bench``: planning-iteration timings, OpenCL vs the numpy reference."""

from __future__ import annotations

import argparse
import os

from nbv_prob_cnn.bench.planning import DEFAULT_CASES, format_table, run_case

NAME = "bench"
HELP = (
    "Benchmarks: planning iterations on half-explored grids (OpenCL vs numpy), CNN inference, TSDF "
    "integration, dense against sparse fusion on the 3DT box and a real room-sized recording (fusion), "
    "the transport overhead of the ROS node split, the CPU cost of a high-rate stream (ros_streams), "
    "the arm (capability map, IK, added cost) and "
    "the cost of rendering the arm into depth frames and filtering it out, and the arm's planning step through the ROS "
    "nodes against the in-process core (arm_loop), and one planning step against the size of the grid and of the "
    "workspace, today's path beside the local one (scale)."
)
SUITES = (
    "planning",
    "sweep",
    "cnn",
    "integrator",
    "fusion",
    "ros",
    "ros_streams",
    "arm",
    "arm_render",
    "arm_loop",
    "scale",
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--suite", choices=(*SUITES, "all"), default="planning", help="what to measure")
    parser.add_argument("--seed", type=int, default=1000, help="world seed of every case")
    parser.add_argument("--repeats", type=int, default=3, help="OpenCL repetitions (best is reported)")
    parser.add_argument("--numpy-origins", type=int, default=3000, help="origins timed on the numpy reference")
    parser.add_argument(
        "--authors-origins", type=int, default=20_000,
        help="origins the authors'-scheme baseline is timed on (then extrapolated to all)",
    )  # fmt: skip
    parser.add_argument("--views", type=int, default=20, help="sweep: views of the timed exploration")
    parser.add_argument("--out", default="docs", help="sweep, scale: folder of the CSV and PNG")
    parser.add_argument(
        "--scale-rows",
        nargs="+",
        choices=("grids", "kitchen"),
        default=["grids", "kitchen"],
        help="scale: the row groups, tabletop-like grids and/or the real kitchen (default: both; the kitchen "
        "alone writes scale_kitchen.csv)",
    )
    parser.add_argument(
        "--ros-grid", default="",
        help="ros: plan on the scale suite's tabletop-like grid of this size, e.g. 256x256x192 "
        "(default: a half-explored 3DU world)",
    )  # fmt: skip
    parser.add_argument("--every", type=int, default=1, help="sweep: time every N-th planned view")
    parser.add_argument("--loop-views", type=int, default=6, help="arm_loop: planning steps timed (first included)")
    parser.add_argument("--log-dir", default="", help="arm_loop: folder of the nodes' logs (default: none)")
    parser.add_argument(
        "--recording", default="", help="fusion: 7-Scenes folder (default: ../shared/data/rgbd/7scenes_redkitchen)"
    )
    parser.add_argument("--fusion-frames", type=int, default=200, help="fusion: frames of the recording fused")
    parser.add_argument(
        "--cases",
        nargs="*",
        help="subset of cases DATASET:N_RAYS[:STRIDE[:METHOD]], e.g. 2d:16 3du:4 3dt:4:1:cnn_prob (default: all)",
    )


def run(args: argparse.Namespace) -> int:
    suites = SUITES if args.suite == "all" else (args.suite,)
    for suite in suites:
        print(f"## {suite}", flush=True)
        runners = {
            "planning": run_planning,
            "sweep": run_sweep,
            "cnn": run_cnn,
            "integrator": run_integrator,
            "fusion": run_fusion,
            "ros": run_ros,
            "ros_streams": run_ros_streams,
            "arm": run_arm,
            "arm_render": run_arm_render,
            "arm_loop": run_arm_loop,
            "scale": run_scale,
        }
        runners[suite](args)
        print(flush=True)
    return 0


def run_scale(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.scale import scale_benchmark

    print(scale_benchmark(seed=args.seed, out_dir=args.out, groups=tuple(args.scale_rows)), flush=True)


def run_ros_streams(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.ros_streams import ros_streams_benchmark

    print(ros_streams_benchmark(), flush=True)


def run_sweep(args: argparse.Namespace) -> None:
    """View search time against explored fraction, per case of ``--cases`` (default 3du:16)."""
    from pathlib import Path

    from nbv_prob_cnn.bench.planning import planning_time_sweep, write_sweep

    for case in (_parse_case(c) for c in (args.cases or ["3du:16"])):
        rows = planning_time_sweep(case.dataset, case.n_rays, args.views, args.seed, every=args.every)
        label = f"{case.dataset}_n{case.n_rays}"
        load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
        csv_path, png = write_sweep(rows, label, Path(args.out), note=f"load average at the end {load}")
        same = all(r[-1] for r in rows)
        print(f"{label}: {len(rows)} iterations, same best view in all: {'yes' if same else 'NO'}; {csv_path}, {png}")


def run_integrator(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.fusion import integrator_benchmark, tsdf_quality
    from nbv_prob_cnn.sensing.sensor_noise import PRESETS

    print(integrator_benchmark(seed=args.seed))
    print("\n| grid quality, 3DT world, 8 views, 640×480 | empty precision | seen-surface recall | "
          "occupied precision | observed fraction |")  # fmt: skip
    print("|---|---|---|---|---|")
    for preset in PRESETS:
        q = tsdf_quality(seed=args.seed, noise=preset)
        print(
            f"| depth noise `{preset}` | {q['empty_precision']:.4f} | {q['surface_recall']:.4f} | "
            f"{q['occupied_precision']:.4f} | {q['observed_fraction']:.4f} |",
            flush=True,
        )


def run_fusion(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.fusion import fusion_suite

    if args.fusion_frames < 1:
        raise ValueError(f"--fusion-frames: must be >= 1, got {args.fusion_frames}")
    print(fusion_suite(recording=args.recording or None, frames=args.fusion_frames), flush=True)


def run_arm(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.arm import arm_benchmark

    print(arm_benchmark(seed=args.seed, iterations=args.repeats))


def run_arm_loop(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.arm_loop import arm_loop_benchmark

    print(arm_loop_benchmark(seed=args.seed, views=args.loop_views, log_dir=args.log_dir or None))


def run_arm_render(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.render import arm_render_benchmark

    print(arm_render_benchmark(seed=args.seed, repeats=max(args.repeats, 10)))


def run_ros(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.ros_latency import ros_latency_benchmark

    shape = None
    if args.ros_grid:
        sizes = args.ros_grid.lower().split("x")
        if len(sizes) != 3 or not all(v.isdigit() and int(v) > 0 for v in sizes):
            raise SystemExit(f"--ros-grid: expected three positive sizes like 256x256x192, got {args.ros_grid!r}")
        shape = (int(sizes[0]), int(sizes[1]), int(sizes[2]))
    print(ros_latency_benchmark(seed=args.seed, shape=shape))


def run_cnn(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.bench.cnn_suite import cnn_layout_table, cnn_table, exploration_plan_table

    def echo(line: str) -> None:  # each row as soon as it is measured (the suite takes a few minutes)
        print(line, flush=True)

    cnn_table(args.seed, args.repeats, echo)
    print()
    print("Planning time per view along a cnn_surface exploration (20 views), on the same grids:", flush=True)
    exploration_plan_table(args.seed, args.repeats, echo=echo)
    print()
    cnn_layout_table(args.seed, args.repeats, echo)


def run_planning(args: argparse.Namespace) -> None:
    from nbv_prob_cnn.gain.opencl import get_ray_caster
    from nbv_prob_cnn.worlds import load_or_generate

    cases = DEFAULT_CASES
    if args.cases:
        cases = tuple(_parse_case(c) for c in args.cases)
    print(f"OpenCL device: {get_ray_caster().device.name.strip()}")
    results = []
    for case in cases:
        world = load_or_generate(case.dataset, args.seed)
        result = run_case(case, world, args.repeats, args.numpy_origins, args.authors_origins)
        results.append(result)
        seconds = ", ".join(f"{k} {t.seconds:.3f} s" for k, t in result.timings.items())
        print(f"{case.label}: {seconds} (numpy extrapolated from {result.numpy_origins} origins)", flush=True)
    print()
    print(
        "iteration = the planner's full iteration (CNN included for cnn_prob); pruned = its view search alone "
        "(exact coarse-to-fine argmax); pruned, all views = the same without pruning views "
        "(prune_views=False); fused = the exhaustive fused view search; "
        "two-step = the previous kernel + "
        "(origins × rays) @ (rays × views); naive = float marching to the first occupied cell + the same "
        "product (a simple kernel of ours, not the authors' scheme); pruned original = the pruned search on the "
        "'original' gain variant; authors = our kernel after the authors' scheme (every sample marched, pow per "
        "sample, the original variant's range and weights) + per-view sums, timed on --authors-origins origins "
        "and extrapolated. Effective samples/s = origins × rays × (R_max + 1) / time (authors and pruned "
        "original: × the original range's samples). Peak memory = tracemalloc peak + OpenCL buffers (torch not "
        "included)."
    )
    print(format_table(results))


def _parse_case(text: str):
    from nbv_prob_cnn.bench.planning import BenchCase

    parts = text.split(":")
    try:
        dataset, n_rays = parts[0], int(parts[1])
        stride = int(parts[2]) if len(parts) > 2 else 1
    except (IndexError, ValueError):
        raise SystemExit(f"--cases: expected DATASET:N_RAYS[:STRIDE[:METHOD]], got {text!r}") from None
    return BenchCase(dataset, n_rays, stride, parts[3] if len(parts) > 3 else "prob_ig")
