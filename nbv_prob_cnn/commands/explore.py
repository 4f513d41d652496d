"""``nbv explore``: one simulated exploration run (docs/method.md#exploration-protocol-and-metrics)."""

from __future__ import annotations

import argparse

import numpy as np

from nbv_prob_cnn.basics.camera import DATASETS
from nbv_prob_cnn.exploration.explore import explore, write_csv
from nbv_prob_cnn.gain import BACKENDS, GAIN_VARIANTS
from nbv_prob_cnn.gain.sampling import SAMPLINGS, SENSOR_MODELS, GainSensor
from nbv_prob_cnn.planners import METHODS, PlanningContext, make_planner

NAME = "explore"
HELP = "Run a simulated next-best-view exploration and log it per view."


def _views(text: str) -> int:
    """``--image-rerank``: a number of views >= 0."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number of views >= 0 (0: no re-ranking), got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", choices=sorted(DATASETS), required=True)
    parser.add_argument("--method", default="prob_ig", choices=list(METHODS),
                        help="next-best-view method (docs/method.md#methods)")  # fmt: skip
    parser.add_argument("--views", type=int, default=20, help="number of views, the random first one included")
    parser.add_argument("--seed", type=int, default=1000, help="world seed (without --scene) and first view")
    parser.add_argument("--scene", help="world .npz from `nbv world` (ground truth; default: generate from --seed)")
    parser.add_argument("--log", required=True, help="per-iteration CSV to write")
    parser.add_argument("--png", help="picture of the result to write")
    parser.add_argument("--backend", choices=BACKENDS, default="auto", help="ray-casting backend")
    parser.add_argument("--n-rays", type=int, help="sub-cells per side of the ray square/cube")
    parser.add_argument(
        "--gain-variant", choices=GAIN_VARIANTS, default="paper",
        help="gain: the paper's equations, or the authors' code's host choices (docs/original_code.md)",
    )  # fmt: skip
    parser.add_argument(
        "--view-set", choices=("spec", "original"), default="spec",
        help="rays and orientations: the paper's, or the authors' code's (docs/original_code.md; not with --n-rays)",
    )  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--noise", default="ideal", help="depth-sensor noise preset: ideal, kinect_v1, astra")
    parser.add_argument("--room-margin", type=float, default=None,
                        help="with --noise: walls this far [m] outside the grid (default: none)")  # fmt: skip
    parser.add_argument("--sensor-model", choices=SENSOR_MODELS, default="paper",
                        help="gain: the paper's, or 'returns': a cell counts by the probability that the "
                             "--noise preset measures it (its ranges, grazing limit; the walls of "
                             "--room-margin; docs/sensing.md)")  # fmt: skip
    parser.add_argument("--sampling", choices=SAMPLINGS, default="rounded",
                        help="the gain's ray samples: the paper's rounded ones, or the exact voxel "
                             "traversal (docs/sensing.md)")  # fmt: skip
    parser.add_argument("--surface-blend", type=float, default=None,
                        help="the surface methods' blend beta in [0, 1]: 0 the paper's gain, 1 the surface alone "
                             "(default: DEFAULT_SURFACE_BLEND, docs/method.md#surface-gain)")  # fmt: skip
    parser.add_argument("--image-rerank", type=_views, default=None, metavar="N",
                        help="the surface methods re-rank the view search's best N views by rays through each "
                             "view's own image (0: no re-ranking; about 0.15 s a plan on the 3DT grid; default: "
                             "DEFAULT_IMAGE_RERANK, docs/method.md#re-ranking-by-the-image-rays)")  # fmt: skip
    parser.add_argument("--stop-surface-cells", type=float, default=0.0,
                        help="stop when the best view is expected to add fewer surface cells than this "
                             "(0: never; docs/method.md#stopping-when-the-surface-is-finished)")  # fmt: skip
    parser.add_argument("--stop-surface-share", type=float, default=0.0,
                        help="stop when the best view is expected to add less surface than this share of the "
                             "surface seen so far (0: never; the larger threshold of the two holds)")  # fmt: skip
    parser.add_argument("--no-guard", action="store_true",
                        help="the paper's plain loop: a view that changed nothing may be taken again")  # fmt: skip
    parser.add_argument("--guard-min-cells", type=int, default=None,
                        help="a pose whose view changed fewer cells is never planned again "
                             "(default: 5e-5 of the grid's cells)")  # fmt: skip
    parser.add_argument("--chamfer", action="store_true",
                        help="3D worlds: also fuse a depth image of the world's meshes per view into a TSDF and "
                             "give the Chamfer distance of its mesh to the meshes after the last view "
                             "(docs/evaluation.md#surface-coverage-and-chamfer-distance)")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.worlds import load_or_generate
    from nbv_prob_cnn.worlds.world import World

    if args.scene:
        from nbv_prob_cnn.perception.saved_grid import saved_file_kind

        if saved_file_kind(args.scene) == "grid":
            raise ValueError(
                f"--scene {args.scene} is a grid a camera has seen (nbv integrate, the integrator's save service), "
                "not a world: nbv explore simulates the camera and needs the ground truth, a world file from "
                "`nbv world --dataset D --seed S --out scene.npz`. To plan on this grid: "
                f"`nbv plan --grid {args.scene}`; to look at it: `nbv view --grid {args.scene} --out grid.png`"
            )
        world = World.load(args.scene, "--scene")
        if world.dataset != args.dataset:
            raise ValueError(f"--scene {args.scene} is a {world.dataset!r} world, not {args.dataset!r}")
    else:
        world = load_or_generate(args.dataset, args.seed)
    from nbv_prob_cnn.sensing.sensor_noise import sensor_noise

    noise = sensor_noise(args.noise)
    gain_sensor = None
    if not noise.is_ideal:  # the preset's ranges, for the "returns" gain
        gain_sensor = GainSensor.from_noise(noise, world.geometry.resolution, walls=args.room_margin is not None)
    elif args.sensor_model == "returns":
        raise ValueError("--sensor-model returns needs a --noise preset (kinect_v1, astra): the ideal sensor "
                         "measures every cell within R_max, so no ranges to know")  # fmt: skip
    planner = make_planner(args.method)
    context = PlanningContext.for_dataset(
        args.dataset,
        rng=np.random.default_rng(args.seed),
        ground_truth=world.ground_truth,
        backend=args.backend,
        n_rays=args.n_rays,
        gain_variant=args.gain_variant,
        view_set=args.view_set,
        sensor_model=args.sensor_model,
        gain_sensor=gain_sensor,
        sampling=args.sampling,
        **({} if args.surface_blend is None else {"surface_blend": args.surface_blend}),
        **({} if args.image_rerank is None else {"image_rerank": args.image_rerank}),
    )
    from nbv_prob_cnn.exploration.view_guard import ViewGuard

    if args.no_guard and args.guard_min_cells is not None:
        raise ValueError("--guard-min-cells and --no-guard exclude each other")
    guard = None if args.no_guard else ViewGuard.for_grid(world.shape, args.guard_min_cells)

    if args.chamfer and world.dims != 3:
        raise ValueError(f"--chamfer needs a 3D world with meshes (3dt, 3du), not {args.dataset}")
    from nbv_prob_cnn.planners.surface_stop import SurfaceStop

    stop = SurfaceStop(args.stop_surface_cells, args.stop_surface_share)
    result = explore(world, planner, context, args.views, progress=not args.quiet, noise=noise,
                     room_margin_m=args.room_margin, guard=guard, chamfer=args.chamfer, stop_surface=stop)  # fmt: skip
    write_csv(result.records, args.log)
    written = [args.log]
    if args.png:
        from nbv_prob_cnn.viz.exploration import save_exploration_png

        title = f"{args.dataset} seed {world.seed}, {planner.name}, {len(result.records)} views"
        save_exploration_png(result, world, args.png, title)
        written.append(args.png)
    last = result.records[-1]
    plan_times = [r.time_total_s for r in result.records[1:]]
    mean_plan = float(np.mean(plan_times)) if plan_times else 0.0
    print(
        f"{args.dataset} seed {world.seed} {planner.name}: {len(result.records)} views, "
        f"unknown fraction {last.unknown_fraction:.4f} (all cells {last.unknown_fraction_all:.4f}), "
        f"surface coverage {last.surface_coverage:.4f}{_views_to_coverage(result)}, "
        f"mean planning time {mean_plan:.3f} s, {result.stop_reason}"
        + ("" if guard is None else f", {len(guard.ruled_out)} views ruled out (< {guard.min_changed_cells} cells)")
        + ("" if result.chamfer is None else f", {result.chamfer.describe()}")
        + f"; wrote {', '.join(written)}"
    )
    return 0


def _views_to_coverage(result) -> str:
    """`` (80/90/95 % after 3/5/- views)``: the views each coverage level took (``-``: not reached)."""
    from nbv_prob_cnn.exploration.surface_metrics import views_to_coverage

    reached = views_to_coverage([r.surface_coverage for r in result.records])
    levels = "/".join(f"{round(100 * level)}" for level in reached)
    counts = "/".join("-" if n is None else str(n) for n in reached.values())
    return f" ({levels} % after {counts} views)"
