"""The exploration session without ROS or a world: a scripted grid source, planner and mover show
each stop rule, the view guard, the interrupt and failed moves (every number worked by hand)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.session import (
    CANCELED,
    ExplorationSession,
    MoveError,
    NoView,
    Outcome,
    PlannedView,
)
from nbv_prob_cnn.exploration.view_guard import ViewGuard, view_key
from nbv_prob_cnn.planners import ViewChoice


def unknown(shape=(4, 4)) -> np.ndarray:
    return np.full(shape, -1, dtype=np.int8)


def known_cells(count: int, shape=(4, 4)) -> np.ndarray:
    """A grid whose first ``count`` cells (row-major) are known empty."""
    grid = unknown(shape)
    grid.reshape(-1)[:count] = 0
    return grid


class Grids:
    """Hands out ``grids`` one after another: the first, then one per move."""

    def __init__(self, grids: list[np.ndarray]) -> None:
        self.grids, self.next, self.stamps = grids, 0, []

    def first_grid(self, interrupt):
        self.next = 1
        return self.grids[0]

    def grid_after(self, stamp_ns, interrupt):
        self.stamps.append(stamp_ns)
        grid = self.grids[min(self.next, len(self.grids) - 1)]
        self.next += 1
        return grid


class Planner:
    """Plans the views of ``views`` in turn (cell (k, 0), orientation 0, gain ``gains[k]``),
    skipping those the guard ruled out; NoView when none is left."""

    def __init__(self, gains: list[float]) -> None:
        self.gains, self.calls = gains, []

    def plan(self, grid, views, guard, interrupt):
        self.calls.append(views)
        for k, gain in enumerate(self.gains):
            choice = ViewChoice(np.array([k, 0]), 0, gain)
            if guard is None or view_key(choice) not in guard.ruled_out:
                return PlannedView(f"view {k}", gain, choice, seconds=0.5)
        return NoView("no view left")


class Mover:
    """Takes every view, failing the ones listed in ``fail`` (by call number) with MoveError."""

    def __init__(self, fail=(), stamp_ns=0) -> None:
        self.fail, self.stamp_ns, self.targets = set(fail), stamp_ns, []

    def move(self, planned, interrupt):
        self.targets.append(planned.target)
        if len(self.targets) - 1 in self.fail:
            raise MoveError(f"arm stalled at {planned.target}")
        self.stamp_ns += 10
        return self.stamp_ns


def run(grids, planner, mover, max_views, **options):
    taken, failed = [], []
    session = ExplorationSession(
        Grids(grids), planner, mover, max_views, on_view=taken.append, on_failed_move=failed.append, **options
    )
    return session.run(), taken, failed


def test_reaches_the_view_budget_with_the_changed_cells_and_fractions():
    grids = [unknown(), known_cells(4), known_cells(4), known_cells(10)]
    mover = Mover()
    result, taken, _ = run(grids, Planner([3.0, 2.0]), mover, 3)
    assert result.outcome is Outcome.SUCCEEDED and result.reason == "reached 3 views"
    assert result.views == 3 and result.failed_moves == 0 and result.guard is None
    assert [t.index for t in taken] == [0, 1, 2]
    assert [t.changed_cells for t in taken] == [4, 0, 6]  # 4 cells became known, then none, then 6 more
    assert [t.unknown_fraction for t in taken] == [12 / 16, 12 / 16, 6 / 16]
    assert [t.ruled_out_views for t in taken] == [0, 0, 0]
    assert mover.targets == ["view 0"] * 3  # without a guard the same view every time
    assert result.unknown_fraction == 6 / 16 and result.grid is grids[3]
    assert taken[0].planned.seconds == 0.5


def test_the_guard_rules_out_views_that_change_nothing_and_the_run_stops_without_views():
    grids = [unknown(), known_cells(4), known_cells(4), known_cells(4)]
    mover = Mover()
    guard = ViewGuard(1)
    result, taken, _ = run(grids, Planner([3.0, 2.0, 1.0]), mover, 10, guard=guard)
    # view 0 changed 4 cells (kept), view 0 again changed none (ruled out), view 1 none (ruled out),
    # view 2 none (ruled out): nothing left after 4 views
    assert mover.targets == ["view 0", "view 0", "view 1", "view 2"]
    assert [t.ruled_out_views for t in taken] == [0, 1, 2, 3]
    assert result.outcome is Outcome.SUCCEEDED and result.views == 4
    assert result.reason == "no view left after 4 views, 3 ruled out for changing < 1 cells"
    assert result.guard is guard and len(guard.ruled_out) == 3


def test_a_guard_made_from_the_first_grids_shape():
    shapes = []

    def make(shape):
        shapes.append(shape)
        return ViewGuard.for_grid(shape)

    result, _, _ = run([unknown((40, 50))], Planner([1.0]), Mover(), 2, guard=make)
    assert shapes == [(40, 50)] and result.guard is not None
    assert result.guard.min_changed_cells == 1  # ceil(5e-5 * 2000) = 1
    assert result.reason == "no view left after 1 views, 1 ruled out for changing < 1 cells"


def test_no_view_without_a_guard_names_the_views_taken():
    result, taken, _ = run([unknown(), known_cells(1)], Planner([]), Mover(), 5)
    assert result.outcome is Outcome.SUCCEEDED and result.reason == "no view left after 0 views"
    assert result.views == 0 and taken == [] and result.unknown_fraction == 1.0


def test_stop_gain_and_stop_unknown_fraction():
    result, _, _ = run([unknown()], Planner([0.25]), Mover(), 5, stop_gain=0.25)
    assert result.reason == "best gain 0.2500 <= 0.25" and result.views == 0
    grids = [unknown(), known_cells(8), known_cells(12)]
    result, taken, _ = run(grids, Planner([1.0]), Mover(), 5, stop_unknown_fraction=0.3)
    # after view 0: 8/16 unknown; after view 1: 4/16 = 0.25 <= 0.3
    assert [t.unknown_fraction for t in taken] == [0.5, 0.25]
    assert result.outcome is Outcome.SUCCEEDED and result.reason == "unknown fraction 0.2500 <= 0.3"


def test_failed_moves_ask_again_and_stop_after_too_many_in_a_row():
    grids = [unknown(), known_cells(2), known_cells(5)]
    planner, mover = Planner([1.0]), Mover(fail={0, 1})
    result, taken, failed = run(grids, planner, mover, 2, max_failed_moves=3)
    assert result.reason == "reached 2 views" and result.views == 2 and result.failed_moves == 2
    assert [f.index for f in failed] == [0, 0] and all(isinstance(f.error, MoveError) for f in failed)
    assert planner.calls == [0, 0, 0, 1]  # asked again after each failure; failures are not views
    assert [t.changed_cells for t in taken] == [2, 3]
    mover = Mover(fail={0, 1, 3, 4})
    result, taken, failed = run(grids, Planner([1.0]), mover, 5, max_failed_moves=2)
    assert len(taken) == 0 and len(failed) == 2 and result.failed_moves == 2
    assert result.reason == "stopped: 2 planned views in a row failed to execute (arm stalled at view 0)"
    mover = Mover(fail={0, 2, 3})  # a success in between resets the count
    result, taken, failed = run(grids, Planner([1.0]), mover, 5, max_failed_moves=2)
    assert len(taken) == 1 and len(failed) == 3 and result.failed_moves == 3
    assert result.reason.startswith("stopped: 2 planned views in a row")


def test_the_mover_stamp_goes_to_the_grid_source():
    source = Grids([unknown(), known_cells(1), known_cells(2)])
    session = ExplorationSession(source, Planner([1.0]), Mover(stamp_ns=100), 2)
    assert session.run().views == 2 and source.stamps == [110, 120]


class InterruptingMover(Mover):
    """Triggers ``interrupt`` with ``reason`` during move number ``at`` and waits through it."""

    def __init__(self, at: int, reason: str) -> None:
        super().__init__()
        self.at, self.reason = at, reason

    def move(self, planned, interrupt):
        if len(self.targets) == self.at:
            interrupt.trigger(self.reason)
            interrupt.wait_until(lambda: False, 5.0)  # raises at once
        return super().move(planned, interrupt)


@pytest.mark.parametrize(
    "reason,outcome,text",
    [(CANCELED, Outcome.CANCELED, "canceled after 1 views"),
     ("node shutting down", Outcome.INTERRUPTED, "stopped after 1 views: node shutting down")],
)  # fmt: skip
def test_an_interrupt_ends_the_run_as_canceled_or_interrupted(reason, outcome, text):
    grids = [unknown(), known_cells(2), known_cells(5)]
    result, taken, _ = run(grids, Planner([1.0]), InterruptingMover(1, reason), 5, interrupt=Interrupt())
    assert result.outcome is outcome and result.reason == text and len(taken) == result.views == 1


def test_an_interrupt_after_the_last_view_still_cancels():
    interrupt = Interrupt()
    taken = []

    def cancel_on_the_last(view):
        taken.append(view)
        if view.index == 1:
            interrupt.trigger(CANCELED)

    session = ExplorationSession(
        Grids([unknown(), known_cells(1), known_cells(2)]), Planner([1.0]), Mover(), 2, interrupt=interrupt,
        on_view=cancel_on_the_last,
    )  # fmt: skip
    result = session.run()
    assert result.outcome is Outcome.CANCELED and result.reason == "canceled after 2 views" and len(taken) == 2


class WaitingGrids(Grids):
    """The first grid comes; the next one never does (the source waits on a condition through the
    interrupt, as the ROS grid holder does)."""

    def __init__(self, timeout_s: float) -> None:
        super().__init__([unknown()])
        self.condition, self.timeout_s = threading.Condition(), timeout_s

    def grid_after(self, stamp_ns, interrupt):
        with self.condition:
            if not interrupt.wait_for(self.condition, lambda: False, self.timeout_s):
                raise TimeoutError(f"no grid including the frame at {stamp_ns} ns within {self.timeout_s:g} s")
        raise AssertionError("unreachable")


def test_an_interrupt_from_another_thread_ends_a_grid_wait_at_once():
    interrupt = Interrupt()
    timer = threading.Timer(0.2, interrupt.trigger, args=(CANCELED,))
    start = time.monotonic()
    timer.start()
    session = ExplorationSession(WaitingGrids(30.0), Planner([1.0]), Mover(), 3, interrupt=interrupt)
    result = session.run()
    elapsed = time.monotonic() - start
    assert result.outcome is Outcome.CANCELED and result.reason == "canceled after 0 views"
    assert elapsed < 5.0, elapsed


def test_a_grid_timeout_fails_the_run_with_the_error():
    result = ExplorationSession(WaitingGrids(0.05), Planner([1.0]), Mover(stamp_ns=5), 3).run()
    assert result.outcome is Outcome.FAILED and isinstance(result.error, TimeoutError)
    assert result.reason == "error: no grid including the frame at 15 ns within 0.05 s" and result.views == 0


def test_a_changed_grid_shape_counts_every_cell_changed():
    result, taken, _ = run([unknown((4, 4)), unknown((3, 5))], Planner([1.0]), Mover(), 1)
    assert result.views == 1 and taken[0].changed_cells == 15


@pytest.mark.parametrize(
    "options,match",
    [({"max_views": 0}, "max_views"), ({"max_failed_moves": 0}, "max_failed_moves"),
     ({"stop_gain": float("nan")}, "stop_gain"), ({"stop_unknown_fraction": float("inf")}, "stop_unknown_fraction")],
)  # fmt: skip
def test_bad_options_are_named(options, match):
    arguments = {"max_views": 3, **options}
    with pytest.raises(ValueError, match=match):
        ExplorationSession(Grids([unknown()]), Planner([1.0]), Mover(), **arguments)


class SurfacePlanner:
    """Plans view k with the predicted new surface ``surfaces[k]`` (None: not known)."""

    def __init__(self, surfaces: list[float | None]) -> None:
        self.surfaces = surfaces

    def plan(self, grid, views, guard, interrupt):
        surface = self.surfaces[min(views, len(self.surfaces) - 1)]
        return PlannedView(f"view {views}", 1.0, ViewChoice(np.array([views, 0]), 0, 1.0), new_surface=surface)


def test_stop_surface_in_cells_and_as_a_share_of_the_surface_seen():
    from nbv_prob_cnn.planners.surface_stop import SurfaceStop

    seen = unknown()
    seen.reshape(-1)[:6] = 1  # 6 surface cells seen
    grids = [unknown(), seen, seen, seen]
    result, taken, _ = run(grids, SurfacePlanner([None, 40.0, 9.0, 1.0]), Mover(), 5,
                           stop_surface=SurfaceStop(cells=10))  # fmt: skip
    # view 0 (no estimate) and view 1 (40 >= 10) are taken; view 2's 9 cells are below 10
    assert len(taken) == 2 and result.outcome is Outcome.SUCCEEDED
    assert result.reason.startswith("surface finished: the best view's predicted new surface 9.0 cells < 10.0")
    # a share of the 6 surface cells: 2.0 x 6 = 12 > 10 cells, the larger threshold holds
    result, taken, _ = run(grids, SurfacePlanner([None, 13.0, 11.0]), Mover(), 5,
                           stop_surface=SurfaceStop(cells=10, share=2.0))  # fmt: skip
    assert len(taken) == 2 and "11.0 cells < 12.0" in result.reason
    # inactive rule: never stops
    result, taken, _ = run(grids, SurfacePlanner([None, 0.0]), Mover(), 3, stop_surface=SurfaceStop())
    assert result.reason == "reached 3 views"


@pytest.mark.parametrize("field,value", [("cells", -1.0), ("share", float("nan")), ("cells", float("inf"))])
def test_bad_surface_stop_thresholds(field, value):
    from nbv_prob_cnn.planners.surface_stop import SurfaceStop

    with pytest.raises(ValueError, match=f"stop_new_surface_{field}"):
        SurfaceStop(**{field: value})
