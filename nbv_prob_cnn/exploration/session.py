"""One exploration, whatever supplies the grid, chooses the views and moves the camera: the loop,
its stop rules and the view guard (:mod:`~nbv_prob_cnn.exploration.view_guard`). No ROS here.

Three parts plug in (small protocols):

* a :class:`GridSource` gives the grid to start from and, after each move, a grid that includes
  the view (the simulation's own state, or the integrator's next grid in ROS);
* a :class:`ViewPlanner` gives the next view (:class:`PlannedView`) or :class:`NoView` with why;
* a :class:`Mover` takes the view (simulates it, or drives the camera or the arm) and raises
  :class:`MoveError` when the robot did not get there.

:meth:`ExplorationSession.run` repeats plan → move → grid until a stop rule holds; the rule and
its :attr:`SessionResult.reason`:

* ``max_views`` views taken: ``reached N views``;
* the unknown fraction of all cells at most ``stop_unknown_fraction`` (> 0):
  ``unknown fraction F <= S``;
* the planner has no view: ``<the planner's reason> after N views``, and how many poses the guard
  ruled out when it ruled any out;
* the planned view's gain at most ``stop_gain``: ``best gain G <= S``;
* the planned view's predicted new surface below ``stop_surface``'s threshold: ``surface finished: ...``;
* ``max_failed_moves`` failed moves in a row: ``stopped: K planned views in a row failed to execute (<error>)``;
* the interrupt, triggered with :data:`CANCELED`: ``canceled after N views`` (outcome ``canceled``);
  with another reason (a shutdown): ``stopped after N views: <its reason>`` (outcome ``interrupted``);
* a ValueError, TimeoutError or RuntimeError of a part: ``error: <error>`` (outcome ``failed``, the
  error kept in :attr:`SessionResult.error`).

A failed move does not count as a view: the planner is asked again (it should rule that view out).
The view guard records each taken view's changed cells (``grid != previous grid``, every cell when
the shape changed) and the planner gets it to plan around the ruled-out poses.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Generic, Protocol, TypeVar

import numpy as np

from nbv_prob_cnn.basics.grid import unknown_fraction_all
from nbv_prob_cnn.basics.interrupt import Interrupt, WaitInterruptedError
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.planners import ViewChoice
from nbv_prob_cnn.planners.surface_stop import SurfaceStop

#: The reason of an interrupt that cancels an exploration (a client's cancel request): the
#: outcome is ``canceled``, not ``interrupted``.
CANCELED = "goal canceled"

TargetT = TypeVar("TargetT")  # what a plan gives the mover: a ViewChoice, a ROS planning response


class MoveError(RuntimeError):
    """The robot did not take the planned view (a rejected goal, a failed execution, an arm that
    did not arrive): the session counts it and asks the planner for another view."""


@dataclass
class PlannedView(Generic[TargetT]):
    """The planner's next view.

    Attributes:
        target: what the mover takes (its own type per planner and mover pair).
        gain: the view's gain (``stop_gain`` compares it).
        choice: its (cell, orientation), which the view guard records; None: not recorded.
        seconds: the planning time (0 for a view that needed no planning, e.g. a random first view).
        new_surface: the most new surface a view can add now, in cells
            (:func:`~nbv_prob_cnn.planners.surface_stop.best_new_surface`), which ``stop_surface``
            compares; None: not known (a random view, no stop rule), never stops.
    """

    target: TargetT
    gain: float
    choice: ViewChoice | None = None
    seconds: float = 0.0
    new_surface: float | None = None


@dataclass
class NoView:
    """The planner has no view left; ``reason`` says why (e.g. no view with positive gain)."""

    reason: str


class GridSource(Protocol):
    def first_grid(self, interrupt: Interrupt) -> np.ndarray:
        """The grid the exploration starts from (may wait for one)."""
        ...

    def grid_after(self, stamp_ns: int, interrupt: Interrupt) -> np.ndarray:
        """A grid that includes what the camera saw from ``stamp_ns`` (:meth:`Mover.move`'s) on;
        may wait for it. Raises TimeoutError when none comes in time."""
        ...


class ViewPlanner(Protocol[TargetT]):
    def plan(
        self, grid: np.ndarray, views: int, guard: ViewGuard | None, interrupt: Interrupt
    ) -> PlannedView[TargetT] | NoView:
        """The next view after ``views`` views, on ``grid`` (the latest the session has; a planner
        may plan on a newer one), never one that ``guard`` has ruled out."""
        ...


class Mover(Protocol[TargetT]):
    def move(self, planned: PlannedView[TargetT], interrupt: Interrupt) -> int:
        """Take the view; returns the stamp (ns) from which grids include it (0: the next grid).

        Raises:
            MoveError: the robot did not get there (the session tries another view).
        """
        ...


class Outcome(Enum):
    SUCCEEDED = "succeeded"  # a stop rule held
    CANCELED = "canceled"  # the interrupt with reason CANCELED
    INTERRUPTED = "interrupted"  # the interrupt with another reason (a shutdown)
    FAILED = "failed"  # an error


@dataclass
class TakenView(Generic[TargetT]):
    """One view taken: what :attr:`ExplorationSession.on_view` gets.

    Attributes:
        index: views taken before this one.
        planned: the plan.
        grid: the grid that includes the view.
        unknown_fraction: of all cells of ``grid``.
        changed_cells: cells whose state the view changed.
        ruled_out_views: poses the view guard has ruled out so far (0 without a guard).
        move_s, grid_wait_s: the move's time and the wait for ``grid``.
    """

    index: int
    planned: PlannedView[TargetT]
    grid: np.ndarray
    unknown_fraction: float
    changed_cells: int
    ruled_out_views: int
    move_s: float
    grid_wait_s: float


@dataclass
class FailedMove(Generic[TargetT]):
    """A move that failed: what :attr:`ExplorationSession.on_failed_move` gets (``index``: views
    taken so far, ``unknown_fraction``: of the latest grid)."""

    index: int
    planned: PlannedView[TargetT]
    error: MoveError
    unknown_fraction: float


@dataclass
class SessionResult:
    """How an exploration ended.

    Attributes:
        outcome: which kind of end.
        reason: why, as the module's table says.
        views: views taken.
        failed_moves: moves that failed, in all.
        unknown_fraction: of all cells of the last grid (1 before any).
        grid: the last grid (None when none came).
        guard: the view guard (None without one).
        error: the error of a ``failed`` outcome.
    """

    outcome: Outcome
    reason: str
    views: int
    failed_moves: int
    unknown_fraction: float
    grid: np.ndarray | None
    guard: ViewGuard | None
    error: Exception | None = None


#: A view guard, or a function of the first grid's shape that makes one (None: no guard).
GuardSpec = ViewGuard | Callable[[tuple[int, ...]], ViewGuard | None] | None


class ExplorationSession(Generic[TargetT]):
    """One exploration with these parts and stop rules (see the module docstring).

    Args:
        grids, planner, mover: the parts.
        max_views: views to take at most (>= 1).
        guard: the view guard, or how to make one from the first grid's shape; None: no guard.
        stop_unknown_fraction: > 0: stop once the unknown fraction of all cells is at most this.
        stop_gain: stop when the planned view's gain is at most this; None: never.
        stop_surface: stop when the planned view's predicted new surface is below its threshold
            (:class:`~nbv_prob_cnn.planners.surface_stop.SurfaceStop`); None: never.
        max_failed_moves: failed moves in a row that stop the exploration (>= 1).
        interrupt: its trigger ends every wait and the exploration (default: one never triggered).
        on_view: called after each view taken.
        on_failed_move: called after each failed move.
    """

    def __init__(
        self,
        grids: GridSource,
        planner: ViewPlanner[TargetT],
        mover: Mover[TargetT],
        max_views: int,
        *,
        guard: GuardSpec = None,
        stop_unknown_fraction: float = 0.0,
        stop_gain: float | None = None,
        stop_surface: SurfaceStop | None = None,
        max_failed_moves: int = 1,
        interrupt: Interrupt | None = None,
        on_view: Callable[[TakenView[TargetT]], None] | None = None,
        on_failed_move: Callable[[FailedMove[TargetT]], None] | None = None,
    ) -> None:
        if isinstance(max_views, bool) or not isinstance(max_views, (int, np.integer)) or max_views < 1:
            raise ValueError(f"max_views: expected at least 1 view, got {max_views}")
        if isinstance(max_failed_moves, bool) or not isinstance(max_failed_moves, int) or max_failed_moves < 1:
            raise ValueError(f"max_failed_moves: expected an integer >= 1, got {max_failed_moves!r}")
        if not np.isfinite(stop_unknown_fraction):
            raise ValueError(f"stop_unknown_fraction: expected a finite fraction, got {stop_unknown_fraction}")
        if stop_gain is not None and not np.isfinite(stop_gain):
            raise ValueError(f"stop_gain: expected a finite gain or None, got {stop_gain}")
        self.grids, self.planner, self.mover = grids, planner, mover
        self.max_views = int(max_views)
        self.guard_spec = guard
        self.stop_unknown_fraction = float(stop_unknown_fraction)
        self.stop_gain = stop_gain
        self.stop_surface = stop_surface if stop_surface is not None and stop_surface.active else None
        self.max_failed_moves = max_failed_moves
        self.interrupt = interrupt if interrupt is not None else Interrupt()
        self.on_view, self.on_failed_move = on_view, on_failed_move

    def _guard(self, shape: tuple[int, ...]) -> ViewGuard | None:
        spec = self.guard_spec
        return spec if spec is None or isinstance(spec, ViewGuard) else spec(shape)

    def run(self) -> SessionResult:
        """Explore until a stop rule holds; never raises for the errors of the table (they end
        the exploration ``failed``)."""
        interrupt = self.interrupt
        views = in_a_row = failed_moves = 0
        fraction, grid, guard = 1.0, None, None

        def end(outcome: Outcome, reason: str, error: Exception | None = None) -> SessionResult:
            return SessionResult(outcome, reason, views, failed_moves, fraction, grid, guard, error)

        try:
            grid = self.grids.first_grid(interrupt)
            fraction = unknown_fraction_all(grid)
            guard = self._guard(grid.shape)
            while views < self.max_views:
                interrupt.check()
                if self.stop_unknown_fraction > 0 and fraction <= self.stop_unknown_fraction:
                    return end(Outcome.SUCCEEDED, f"unknown fraction {fraction:.4f} <= {self.stop_unknown_fraction}")
                planned = self.planner.plan(grid, views, guard, interrupt)
                interrupt.check()  # a plan interrupted while it waited may answer "no view"
                if isinstance(planned, NoView):
                    return end(Outcome.SUCCEEDED, no_view_reason(planned.reason, views, guard))
                if self.stop_gain is not None and planned.gain <= self.stop_gain:
                    return end(Outcome.SUCCEEDED, f"best gain {planned.gain:.4f} <= {self.stop_gain}")
                if self.stop_surface is not None and planned.new_surface is not None:
                    finished = self.stop_surface.reason(grid, planned.new_surface)
                    if finished is not None:
                        return end(Outcome.SUCCEEDED, finished)
                moving = time.perf_counter()
                try:
                    stamp_ns = self.mover.move(planned, interrupt)
                except MoveError as exc:
                    in_a_row, failed_moves = in_a_row + 1, failed_moves + 1
                    if self.on_failed_move is not None:
                        self.on_failed_move(FailedMove(views, planned, exc, fraction))
                    if in_a_row >= self.max_failed_moves:
                        reason = f"stopped: {in_a_row} planned views in a row failed to execute ({exc})"
                        return end(Outcome.SUCCEEDED, reason)
                    continue
                in_a_row = 0
                waiting = time.perf_counter()
                seen = self.grids.grid_after(stamp_ns, interrupt)
                done = time.perf_counter()
                changed = int(np.count_nonzero(seen != grid)) if seen.shape == grid.shape else int(seen.size)
                grid, fraction = seen, unknown_fraction_all(seen)
                if guard is not None and planned.choice is not None:
                    guard.record(planned.choice, changed)
                ruled_out = 0 if guard is None else len(guard.ruled_out)
                taken = TakenView(views, planned, seen, fraction, changed, ruled_out, waiting - moving, done - waiting)
                if self.on_view is not None:
                    self.on_view(taken)
                views += 1
            interrupt.check()
        except WaitInterruptedError as exc:
            if interrupt.reason == CANCELED:
                return end(Outcome.CANCELED, f"canceled after {views} views")
            return end(Outcome.INTERRUPTED, f"stopped after {views} views: {exc}")
        except (ValueError, TimeoutError, RuntimeError) as exc:
            return end(Outcome.FAILED, f"error: {exc}", exc)
        return end(Outcome.SUCCEEDED, f"reached {self.max_views} views")


def no_view_reason(reason: str, views: int, guard: ViewGuard | None) -> str:
    """Why an exploration stopped without a view: the planner's ``reason``, the views taken and
    the poses the guard ruled out (when it ruled any out)."""
    text = f"{reason} after {views} views"
    if guard is not None and guard.ruled_out:
        text += f", {len(guard.ruled_out)} ruled out for changing < {guard.min_changed_cells} cells"
    return text
