"""The exploration protocol of docs/method.md#exploration-protocol-and-metrics: start all-unknown, a random
first view, then the
planner's views, each simulated and merged, logged per iteration."""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np
from tqdm import tqdm

from nbv_prob_cnn.basics.grid import unknown_fraction
from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.mesh_chamfer import ChamferResult
from nbv_prob_cnn.exploration.session import ExplorationSession, NoView, PlannedView, TakenView
from nbv_prob_cnn.exploration.surface_metrics import SurfaceCoverage
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.planners import Planner, PlanningContext, ViewChoice
from nbv_prob_cnn.planners.surface_stop import SurfaceStop
from nbv_prob_cnn.sensing.observe import observe
from nbv_prob_cnn.sensing.sensor_noise import SensorNoise
from nbv_prob_cnn.worlds.world import World

CSV_COLUMNS = [
    "iteration", "unknown_fraction", "unknown_fraction_all", "gain",
    "time_total_s", "time_cnn_s", "time_raycast_s", "time_views_s",
    "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw", "changed_cells", "ruled_out_views", "surface_coverage",
    "new_surface_cells",
]  # fmt: skip
#: Units of the columns: fractions and gains are ratios; times in seconds (``_s``); the camera
#: position in metres of the grid frame (``_m``); the quaternion (x, y, z, w) of the camera;
#: counts of cells (``changed_cells``: cells whose state the view changed) and of views
#: (``ruled_out_views``: poses the view guard has ruled out after this view; 0 without a guard);
#: ``surface_coverage``: the share of the ground-truth surface seen so far, of the surface facing
#: the first view's free space (:meth:`~nbv_prob_cnn.exploration.surface_metrics.SurfaceCoverage.seen_from`);
#: ``new_surface_cells``: the most new surface, in cells, a view could add before this one, on the
#: method's map (:func:`~nbv_prob_cnn.planners.surface_stop.best_new_surface`), what the stop rule
#: compares; logged only with a stop rule (a second view search per view), empty otherwise.


@dataclass
class IterationRecord:
    """One view of a run: state after merging it, the planner's gain and stage times."""

    iteration: int
    unknown_fraction: float
    unknown_fraction_all: float
    gain: float
    time_total_s: float
    time_cnn_s: float
    time_raycast_s: float
    time_views_s: float
    cell: np.ndarray
    position_m: np.ndarray
    quaternion: np.ndarray
    changed_cells: int = 0
    ruled_out_views: int = 0
    surface_coverage: float = float("nan")
    new_surface_cells: float = float("nan")

    def csv_row(self) -> list:
        return [
            self.iteration,
            f"{self.unknown_fraction:.6f}",
            f"{self.unknown_fraction_all:.6f}",
            f"{self.gain:.6g}",
            f"{self.time_total_s:.6f}",
            f"{self.time_cnn_s:.6f}",
            f"{self.time_raycast_s:.6f}",
            f"{self.time_views_s:.6f}",
            *(f"{v:.6f}" for v in self.position_m),
            *(f"{v:.6f}" for v in self.quaternion),
            self.changed_cells,
            self.ruled_out_views,
            f"{self.surface_coverage:.6f}",
            "" if np.isnan(self.new_surface_cells) else f"{self.new_surface_cells:.3f}",
        ]


@dataclass
class ExplorationResult:
    """The per-view log, the final grid and why the run stopped; with ``chamfer``, the Chamfer
    distance of the run's TSDF mesh to the world's meshes after the last view."""

    records: list[IterationRecord]
    state: np.ndarray
    stop_reason: str
    chamfer: ChamferResult | None = None


def first_view(world: World, context: PlanningContext) -> ViewChoice:
    """A random ground-truth-empty cell and a random candidate orientation."""
    free = np.argwhere(world.ground_truth == 0)
    if free.shape[0] == 0:
        raise ValueError("world: has no empty cell to place the first view")
    cell = free[context.rng.integers(free.shape[0])]
    return ViewChoice(cell, int(context.rng.integers(context.orientations.shape[0])), float("nan"))


def explore(
    world: World,
    planner: Planner,
    context: PlanningContext,
    views: int,
    progress: bool = True,
    noise: SensorNoise | None = None,
    room_margin_m: float | None = None,
    first: ViewChoice | None = None,
    guard: ViewGuard | None = None,
    chamfer: bool = False,
    stop_surface: SurfaceStop | None = None,
) -> ExplorationResult:
    """Run one exploration of ``world`` with ``planner`` for at most ``views`` views.

    The first view is ``first`` if given, else random (docs/method.md#exploration-protocol-and-metrics); the
    run stops early when the
    planner finds no view (no positive gain, or, for a constrained planner, none it can take).
    While no cell is known empty (a noisy first view without returns) the next view is random
    too; with the exact sensor this never happens (a view always sees its own cell).
    ``noise``: a depth-sensor model for the simulated views (exact if None); ``room_margin_m``:
    with ``noise``, walls this far outside the grid (see :func:`observe`). ``guard``: rules out
    each pose whose view changed fewer than its threshold of cells, plans around the ruled-out
    poses and stops when nothing else has positive gain (:mod:`~nbv_prob_cnn.exploration.view_guard`);
    None: the paper's plain loop. The loop and its stop rules are the
    :class:`~nbv_prob_cnn.exploration.session.ExplorationSession`'s, with the world as grid source
    and mover. ``chamfer``: also fuse a depth image of the world's meshes per view into a TSDF and
    give the Chamfer distance of its mesh after the last view
    (:class:`~nbv_prob_cnn.exploration.mesh_chamfer.MeshReconstruction`; 3D worlds only).
    ``stop_surface``: stop once the planned view's predicted new surface is below its threshold
    (docs/method.md#stopping-when-the-surface-is-finished).
    """
    if views < 1:
        raise ValueError(f"views: expected at least 1 view, got {views}")
    simulated = SimulatedWorld(world, context, noise, room_margin_m)
    records: list[IterationRecord] = []
    coverages: list[SurfaceCoverage] = []  # of the first view's free space, made at the first view
    reconstruction = None
    if chamfer:
        from nbv_prob_cnn.exploration.mesh_chamfer import MeshReconstruction  # open3d only when asked

        reconstruction = MeshReconstruction(world, context.active_sensor, noise, room_margin_m)
    bar = tqdm(total=views, desc=f"{world.dataset} {planner.name}", unit="view", disable=not progress)

    def record(taken: TakenView[ViewChoice]) -> None:
        choice = taken.planned.target
        if not coverages:
            coverages.append(SurfaceCoverage.seen_from(world.ground_truth, choice.cell))
        records.append(
            IterationRecord(
                iteration=taken.index,
                unknown_fraction=unknown_fraction(taken.grid, world.ground_truth),
                unknown_fraction_all=taken.unknown_fraction,
                gain=choice.gain,
                time_total_s=taken.planned.seconds,
                time_cnn_s=choice.times["cnn"],
                time_raycast_s=choice.times["raycast"],
                time_views_s=choice.times["views"],
                cell=np.asarray(choice.cell).copy(),
                position_m=world.geometry.cell_centre(choice.cell),
                quaternion=context.view_quaternion(choice.view_index),
                changed_cells=taken.changed_cells,
                ruled_out_views=taken.ruled_out_views,
                surface_coverage=coverages[0](taken.grid),
                new_surface_cells=taken.planned.new_surface if taken.planned.new_surface is not None else float("nan"),
            )
        )
        if reconstruction is not None:
            reconstruction.add_view(records[-1].position_m, records[-1].quaternion)
        bar.update(1)
        bar.set_postfix(
            unknown=f"{records[-1].unknown_fraction:.3f}",
            surface=f"{records[-1].surface_coverage:.3f}",
            plan_s=f"{taken.planned.seconds:.2f}",
        )

    session = ExplorationSession(
        simulated,
        SimulatedPlanner(
            world, planner, context, first, estimate_surface=stop_surface is not None and stop_surface.active
        ),
        simulated,
        views,
        guard=guard,
        on_view=record,
        stop_surface=stop_surface,
    )
    result = session.run()
    bar.close()
    if result.error is not None:
        raise result.error
    distance = None if reconstruction is None else reconstruction.chamfer()
    return ExplorationResult(records, simulated.state, result.reason, distance)


class SimulatedWorld:
    """Grid source and mover of a simulated exploration: the state starts all unknown, and a move
    observes the world from the view (:func:`observe`)."""

    def __init__(
        self, world: World, context: PlanningContext, noise: SensorNoise | None, room_margin_m: float | None
    ) -> None:
        self.world, self.context, self.noise, self.room_margin_m = world, context, noise, room_margin_m
        self.state = np.full(world.shape, -1, dtype=np.int8)

    def first_grid(self, interrupt: Interrupt) -> np.ndarray:
        return self.state.copy()

    def move(self, planned: PlannedView[ViewChoice], interrupt: Interrupt) -> int:
        choice, world, context = planned.target, self.world, self.context
        observe(self.state, world.ground_truth, choice.cell, context.orientations[choice.view_index],
                context.active_sensor, noise=self.noise, rng=context.rng, resolution_m=world.resolution,
                room_margin_m=self.room_margin_m)  # fmt: skip
        return 0

    def grid_after(self, stamp_ns: int, interrupt: Interrupt) -> np.ndarray:
        return self.state.copy()


class SimulatedPlanner:
    """The views of a simulated exploration: ``first`` (or a random one) first, a random one while
    no cell is known empty, else the planner's best (around the guard's ruled-out poses)."""

    def __init__(
        self,
        world: World,
        planner: Planner,
        context: PlanningContext,
        first: ViewChoice | None,
        estimate_surface: bool = False,
    ) -> None:
        self.world, self.planner, self.context, self.first = world, planner, context, first
        self.estimate_surface = estimate_surface  # the stop rule's estimate: a second view search per view

    def plan(
        self, grid: np.ndarray, views: int, guard: ViewGuard | None, interrupt: Interrupt
    ) -> PlannedView[ViewChoice] | NoView:
        if views == 0 and self.first is not None:
            return PlannedView(self.first, self.first.gain, self.first)
        if views == 0 or not np.any(grid == 0):
            # nothing is known to be free, so nothing to plan from (a noisy sensor's view can return
            # nothing, e.g. inside its minimum range): another random view, as the first one
            choice = first_view(self.world, self.context)
            return PlannedView(choice, choice.gain, choice)
        start = time.perf_counter()
        if guard is None:
            planned = self.planner.plan(grid, self.context)
        else:
            planned = guard.plan(self.planner, grid, self.context)
        seconds = time.perf_counter() - start
        if planned is None:
            return NoView("no view with positive gain (or none feasible)")
        estimate = planned.surface_estimate if self.estimate_surface else None
        return PlannedView(planned, planned.gain, planned, seconds, estimate() if estimate is not None else None)


def write_csv(records: list[IterationRecord], path: str | Path | TextIO) -> None:
    """Write the per-iteration log with the columns of :data:`CSV_COLUMNS` (to a file path or an
    open text stream)."""
    if not isinstance(path, (str, Path)):  # an open text stream
        _write_rows(records, path)
        return
    with open(path, "w", newline="") as handle:
        _write_rows(records, handle)


def _write_rows(records: list[IterationRecord], handle: TextIO) -> None:
    writer = csv.writer(handle)
    writer.writerow(CSV_COLUMNS)
    for record in records:
        writer.writerow(record.csv_row())
