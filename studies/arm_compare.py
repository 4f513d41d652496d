"""``nbv study arm_compare``: simulated 3DT explorations with a free-flying camera and with the arm
constraint (λ = 0 and λ > 0), or (``--paths``) the arm with straight joint paths only against
the arm with planned paths where the straight one is blocked (:mod:`nbv_prob_cnn.arm.path_planning`);
per-run CSVs (a re-run skips finished runs), a summary CSV, a markdown table and a PNG."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from studies._command import run_command

HELP = "Compare free-flying and arm-constrained 3DT explorations (unknown fraction, joint travel, stage times)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output folder (runs/ inside it holds the per-run CSVs)")
    parser.add_argument("--scenes", type=int, default=10, help="number of 3DT worlds, seeds first-seed, +1, ...")
    parser.add_argument("--first-seed", type=int, default=1000, help="first world seed (held-out: >= 1000)")
    parser.add_argument("--views", type=int, default=30, help="views per run, the shared first view included")
    parser.add_argument("--method", default="prob_ig", help="gain method (a GainPlanner method)")
    parser.add_argument("--motion-weight", type=float, default=0.1, help="the λ > 0 of the third configuration")
    parser.add_argument("--stride", type=int, default=8, help="capability-map lattice stride (cells)")
    parser.add_argument("--top-k", type=int, default=200, help="ranked views handed to the exact check")
    parser.add_argument("--max-checks", type=int, default=30, help="exact checks per iteration at most (0: all)")
    parser.add_argument(
        "--free-above", type=float, default=0.4, help="tabletop prior: unknown above this height (m) does not block"
    )
    parser.add_argument(
        "--ik-alternatives", type=int, default=4, help="other IK solutions tried when the first one collides"
    )
    parser.add_argument(
        "--loose-capability",
        action="store_true",
        help="capability lookup: OR of the lattice nodes around a cell (default: AND, fewer IK failures)",
    )
    parser.add_argument(
        "--fallback-radius",
        type=float,
        default=0.25,
        help="when no ranked view is feasible, rank again within this distance (m) of the camera (0: off)",
    )
    parser.add_argument(
        "--no-swept",
        action="store_true",
        help="do not treat the space the arm has swept as free (the arm then sees only the camera's map)",
    )
    parser.add_argument(
        "--paths",
        action="store_true",
        help="compare straight joint paths only against planned paths (OMPL) where the straight one is blocked, "
        "both λ = 0, instead of free-flying / λ = 0 / λ > 0",
    )
    parser.add_argument("--path-timeout", type=float, default=1.0, help="--paths: planning time limit per goal (s)")
    parser.add_argument(
        "--path-resolution", type=float, default=0.05, help="--paths: motion-validation resolution (rad, joint space)"
    )
    parser.add_argument("--path-attempts", type=int, default=3, help="--paths: paths planned per iteration at most")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    """Run the scenes' missing runs, then summarize every run (module docstring); 0 when done.

    Raises:
        ValueError: an option out of its range.
    """
    from tqdm import tqdm

    from nbv_prob_cnn.arm.capability import load_or_build_capability_map
    from nbv_prob_cnn.arm.collision import CollisionChecker
    from nbv_prob_cnn.arm.feasibility import ArmFeasibility
    from nbv_prob_cnn.arm.path_planning import JointPathPlanner, PathPlannerSettings
    from nbv_prob_cnn.arm.robot import RobotModel
    from nbv_prob_cnn.arm.swept import SweptVolume
    from nbv_prob_cnn.basics.camera import dataset_defaults
    from nbv_prob_cnn.exploration.explore import explore
    from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner, Planner, PlanningContext
    from nbv_prob_cnn.worlds import load_or_generate
    from studies.arm_comparison import (
        ArmPlanner,
        config_name,
        reachable_first_view,
        read_run_csv,
        run_rows,
        save_comparison_png,
        summarize,
        write_run_csv,
        write_summary,
    )

    if args.method not in GAIN_METHODS:
        raise ValueError(f"--method: expected one of {sorted(GAIN_METHODS)}, got {args.method!r}")
    if args.ik_alternatives < 0:
        raise ValueError(f"--ik-alternatives: expected >= 0, got {args.ik_alternatives}")
    if args.scenes < 1 or args.views < 1:
        raise ValueError("--scenes and --views: expected at least 1")
    if not (np.isfinite(args.motion_weight) and args.motion_weight > 0):
        raise ValueError(f"--motion-weight: expected a finite λ > 0, got {args.motion_weight}")
    settings = PathPlannerSettings(
        timeout_s=args.path_timeout, resolution_rad=args.path_resolution, max_attempts=args.path_attempts
    )  # raises ValueError on bad values
    out = Path(args.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    seeds = list(range(args.first_seed, args.first_seed + args.scenes))
    # (λ or None for free-flying, planned paths); --paths: the planned configuration first in each scene
    variants: list[tuple[float | None, bool]] = (
        [(0.0, True), (0.0, False)] if args.paths else [(None, False), (0.0, False), (args.motion_weight, False)]
    )
    configs = [config_name(w, p) for w, p in variants]
    runs: dict[str, list] = {c: [] for c in configs}

    robot = RobotModel()
    checker = CollisionChecker(robot, spacing=0.75 * dataset_defaults("3dt").resolution_m)

    def feasibility(weight: float, seed: int, capability, planned: bool = False) -> ArmFeasibility:
        path_planner = JointPathPlanner(checker, dataclasses.replace(settings, seed=seed)) if planned else None
        return ArmFeasibility(
            robot,
            checker,
            capability=capability,
            motion_weight=weight,
            free_above_m=args.free_above,
            max_checks=args.max_checks,
            rng=np.random.default_rng(seed),
            ik_alternatives=args.ik_alternatives,
            strict_capability=not args.loose_capability,
            path_planner=path_planner,
        )

    def context(world) -> PlanningContext:
        return PlanningContext.for_dataset(
            "3dt", rng=np.random.default_rng(world.seed), ground_truth=world.ground_truth
        )

    capability = None
    bar = tqdm(total=len(seeds) * len(configs), desc="arm-compare", unit="run", disable=args.quiet)
    # --paths: every scene's planned run first, then the straight-only runs (a run cut short by
    # time leaves whole configurations over the first scenes); otherwise all configurations per scene
    passes = [[v] for v in variants] if args.paths else [variants]
    for group in passes:
        for seed in seeds:
            paths = {config_name(w, p): out / "runs" / f"seed{seed}_{config_name(w, p)}.csv" for w, p in group}
            todo = [(w, p) for w, p in group if not paths[config_name(w, p)].is_file()]
            bar.update(len(group) - len(todo))
            if todo:
                world = load_or_generate("3dt", seed)
                geometry = world.geometry
                if capability is None:
                    capability = load_or_build_capability_map(robot, geometry, args.stride, progress=not args.quiet)
                arm = feasibility(0.0, seed, capability)
                first, start = reachable_first_view(world, context(world), arm, np.random.default_rng(seed))
            for weight, planned in todo:
                name = config_name(weight, planned)
                gain_planner = GainPlanner(GAIN_METHODS[args.method])
                planner: Planner = gain_planner
                moves = None
                if weight is not None:
                    constrained = feasibility(weight, seed, capability, planned)
                    swept = None if args.no_swept else SweptVolume(checker, geometry)
                    arm_planner = ArmPlanner(
                        gain_planner, constrained, geometry, start, args.top_k, swept, args.fallback_radius, first
                    )
                    planner, moves = arm_planner, arm_planner.moves
                ctx = context(world)
                bar.set_postfix(seed=seed, config=name)
                result = explore(world, planner, ctx, args.views, progress=False, first=first)
                write_run_csv(run_rows(result, ctx, moves), paths[name])
                bar.update(1)
    for c in configs:
        runs[c] = [read_run_csv(out / "runs" / f"seed{seed}_{c}.csv") for seed in seeds]
    bar.close()

    if args.paths:
        return _report_paths(args, runs, seeds, settings)
    summaries = summarize(runs, args.views)
    header = (
        f"3DT seeds {seeds[0]}..{seeds[-1]} ({len(seeds)} scenes) x {args.views} views, method {args.method}, "
        f"λ > 0 = {args.motion_weight:g}, capability stride {args.stride}, top_k {args.top_k}, "
        f"max_checks {args.max_checks}, unknown free above {args.free_above} m, "
        f"swept space free: {'no' if args.no_swept else 'yes'}, IK alternatives {args.ik_alternatives}, "
        f"capability lookup {'OR' if args.loose_capability else 'AND'} of the surrounding nodes, "
        f"near-camera fallback radius {args.fallback_radius:g} m"
    )
    write_summary(summaries, out / "summary.csv", out / "summary.md", args.views, header)
    save_comparison_png(summaries, out / "comparison.png", f"3DT, {len(seeds)} scenes, {args.method}")
    for s in summaries:
        print(
            f"{s.config}: {s.runs} runs, unknown fraction after {args.views} views {s.unknown_final_mean:.4f} "
            f"± {s.unknown_final_std:.4f}, joint travel {s.joint_travel_mean:.2f} rad, per view gain "
            f"{s.time_gain_mean:.3f} s, capability {s.time_capability_mean:.3f} s, "
            f"IK+collision {s.time_ik_collision_mean:.3f} s"
        )
    print(f"wrote {out / 'summary.csv'}, {out / 'summary.md'}, {out / 'comparison.png'}")
    return 0


def _report_paths(args: argparse.Namespace, runs: dict[str, list], seeds: list[int], settings) -> int:
    """Summary, table and PNG of ``--paths``."""
    from studies.arm_comparison import save_paths_png, summarize_paths, write_paths_summary

    out = Path(args.out)
    summaries = summarize_paths(runs, args.views)
    header = (
        f"3DT seeds {seeds[0]}..{seeds[-1]} ({len(seeds)} scenes) x {args.views} views, method {args.method}, λ = 0, "
        f"straight joint paths only against planned paths (OMPL RRTConnect + simplifier, time limit "
        f"{settings.timeout_s:g} s per goal, at most {settings.max_attempts} per iteration, motion validation every "
        f"{settings.resolution_rad:g} rad) where the straight one is blocked; capability stride {args.stride}, "
        f"top_k {args.top_k}, max_checks {args.max_checks}, unknown free above {args.free_above} m, "
        f"swept space free: {'no' if args.no_swept else 'yes'}, IK alternatives {args.ik_alternatives}, "
        f"near-camera fallback radius {args.fallback_radius:g} m"
    )
    write_paths_summary(summaries, out / "summary.csv", out / "summary.md", header)
    save_paths_png(summaries, out / "comparison.png", f"3DT, {len(seeds)} scenes, {args.method}: straight vs planned")
    for s in summaries:
        after = ", ".join(f"{n}: {v:.4f}" for n, v in s.unknown_at.items())
        print(
            f"{s.config}: {s.runs} runs, feasible iterations {100 * s.feasible_fraction:.1f} %, unknown after {after}, "
            f"joint travel {s.joint_travel_mean:.2f} rad, path planning {s.times['path_planning']:.3f} s/view"
        )
    print(f"wrote {out / 'summary.csv'}, {out / 'summary.md'}, {out / 'comparison.png'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``nbv study arm_compare [args]`` (or ``nbv study arm_compare``)."""
    return run_command("arm_compare", HELP, add_arguments, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
