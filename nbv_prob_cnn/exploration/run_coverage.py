"""The surface coverage of each view of a run in a known world, measured on the grids that a
mapping process (e.g. the ROS ``integrator``) builds in the world's frame: what the simulated
main job prints per view and keeps in ``views.csv``.

The coverage is :mod:`~nbv_prob_cnn.exploration.surface_metrics`' (as ``nbv explore`` and ``nbv
evaluate`` report it): the share of the ground-truth surface that faces the first view's free
space (:meth:`~nbv_prob_cnn.exploration.surface_metrics.SurfaceCoverage.seen_from`) with a cell seen
occupied within one cell of it. The first view is the first one measured: its camera position
fixes that free space (all the surface when the position lies outside the grid or in a cell the
ground truth holds occupied). The surface is found once, at that first view; each view then costs
one gather over the surface cells' neighbourhoods (no ROS here: callers convert their grid
messages with :func:`~nbv_prob_cnn.ros.conversions.msg_to_grid`). :class:`ViewsAwaitingGrids`
holds a run's per-view reports until each view's own grid has come.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import unknown_fraction_all
from nbv_prob_cnn.exploration.surface_metrics import SurfaceCoverage
from nbv_prob_cnn.worlds.world import World

#: Grid origins and cell sizes within this many metres are the same placement.
GEOMETRY_TOLERANCE_M = 1e-6

T = TypeVar("T")
#: The grid at hand and its placement (None before any): called only when a view waits for one.
GridSource = Callable[[], "tuple[np.ndarray, GridGeometry] | None"]


class RunCoverage:
    """Surface coverage per view of one run in one world (a new run needs a new instance: the
    first view measured fixes the surface)."""

    def __init__(self, ground_truth: np.ndarray, geometry: GridGeometry) -> None:
        truth = np.asarray(ground_truth)
        if truth.shape != tuple(geometry.shape):
            raise ValueError(f"ground_truth: shape {truth.shape} differs from its geometry's {tuple(geometry.shape)}")
        self.ground_truth, self.geometry = truth, geometry
        self._coverage: SurfaceCoverage | None = None

    @classmethod
    def of_world(cls, world: World) -> RunCoverage:
        return cls(world.ground_truth, world.geometry)

    @property
    def surface(self) -> SurfaceCoverage | None:
        """The surface measured against (None before the first view)."""
        return self._coverage

    def check_geometry(self, geometry: GridGeometry) -> None:
        """Raises ValueError, naming both placements, unless a grid of ``geometry`` lies cell for
        cell on the ground truth (same shape, origin and cell size within
        :data:`GEOMETRY_TOLERANCE_M`)."""
        same = (
            tuple(geometry.shape) == tuple(self.geometry.shape)
            and abs(geometry.resolution - self.geometry.resolution) <= GEOMETRY_TOLERANCE_M
            and np.allclose(geometry.origin, self.geometry.origin, rtol=0.0, atol=GEOMETRY_TOLERANCE_M)
        )
        if not same:
            raise ValueError(
                f"grid: shape {tuple(geometry.shape)}, origin {tuple(geometry.origin)} m, cell "
                f"{geometry.resolution} m does not lie on the world's ground truth (shape "
                f"{tuple(self.geometry.shape)}, origin {tuple(self.geometry.origin)} m, "
                f"cell {self.geometry.resolution} m)"
            )

    def __call__(self, state: np.ndarray, geometry: GridGeometry, camera_position_m: np.ndarray) -> float:
        """The coverage of ``state`` (ternary, placed by ``geometry``: the grid after a view taken
        from ``camera_position_m``, metres in the grid's frame; only the first call's position is used).

        Raises:
            ValueError: ``geometry`` does not lie on the ground truth, or ``state`` has another shape.
        """
        self.check_geometry(geometry)
        if self._coverage is None:
            cell, inside = self.geometry.containing_cell(np.asarray(camera_position_m, dtype=np.float64))
            if inside:
                self._coverage = SurfaceCoverage.seen_from(self.ground_truth, cell)
            else:
                self._coverage = SurfaceCoverage(self.ground_truth)
        return self._coverage(state)


@dataclass
class _Waiting(Generic[T]):
    item: T
    view: tuple[float, np.ndarray] | None  # a taken view's unknown fraction and camera position; None: no grid


class ViewsAwaitingGrids(Generic[T]):
    """A run's per-view reports (``item``), each taken view's held until its own grid has come, then
    released in arrival order with its coverage (``release(item, coverage)``; None for a report of no
    view or one whose grid never came).

    A view's grid is identified by the unknown fraction its report carries (``float32``, as in an
    Explore feedback): the grid the planner waited for after the move. A process that hears the
    reports and the grids on separate channels may get a report before its grid (the main job's
    client did, for 2 of 5 views of one run); measuring on the grid at hand would then give the
    view before's coverage. A view still waiting when the next view's report comes, or at
    :meth:`give_up`, is released without a coverage and counted in ``missed``.
    """

    def __init__(self, coverage: RunCoverage, release: Callable[[T, float | None], None]) -> None:
        self.coverage, self.release = coverage, release
        self.missed = 0
        self.off = ""  # why the coverage was turned off (a grid off the world's placement), "" while on
        self._queue: list[_Waiting[T]] = []

    @property
    def waiting(self) -> bool:
        return bool(self._queue)

    def add(self, item: T, view: tuple[float, np.ndarray] | None, grid: GridSource) -> None:
        """A report: of a taken view (``view`` = its reported unknown fraction and camera position,
        metres) or of no view (None); ``grid()`` gives the grid at hand (None before any)."""
        if view is not None and not self.off:
            self._release_waiting_views()
        self._queue.append(_Waiting(item, None if self.off else view))
        self.offer(grid)

    def offer(self, grid: GridSource) -> None:
        """A grid may have come: release the reports in order up to the first view whose grid
        ``grid()`` is not."""
        loaded: tuple[np.ndarray, GridGeometry] | None = None
        while self._queue:
            head = self._queue[0]
            if head.view is None:
                self.release(self._queue.pop(0).item, None)
                continue
            loaded = loaded or grid()
            if loaded is None:
                return
            state, geometry = loaded
            if np.float32(unknown_fraction_all(state)) != np.float32(head.view[0]):
                return
            try:
                value = self.coverage(state, geometry, head.view[1])
            except ValueError as exc:
                self.off = str(exc)
                self._release_waiting_views(count=False)
                return
            self.release(self._queue.pop(0).item, value)

    def give_up(self) -> None:
        """The run ended: release what still waits, views without a coverage (counted)."""
        self._release_waiting_views()

    def _release_waiting_views(self, count: bool = True) -> None:
        for waiting in self._queue:
            self.missed += int(count and waiting.view is not None)
            self.release(waiting.item, None)
        self._queue.clear()
