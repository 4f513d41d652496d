"""RunCoverage: the surface coverage per view of a run in a known world, on grids placed in the
world's frame (what the simulated main job keeps in views.csv), against hand-counted cells."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.exploration.run_coverage import RunCoverage, ViewsAwaitingGrids

#: A 7x5x5 world of 0.1 m cells at (1, 2, 0) m: a wall three cells thick (x = 2, 3, 4) between two
#: free spaces, x = 0..1 (left) and x = 5..6 (right). The surface facing the left is the x = 2
#: plane (25 cells), facing the right the x = 4 plane (25 cells).
GEOMETRY = GridGeometry((1.0, 2.0, 0.0), 0.1, (7, 5, 5))
LEFT, RIGHT = (1.05, 2.25, 0.25), (1.65, 2.25, 0.25)  # centres of cells (0, 2, 2) and (6, 2, 2)


def wall_world() -> np.ndarray:
    truth = np.zeros(GEOMETRY.shape, np.uint8)
    truth[2:5] = 1
    return truth


def seen_column() -> np.ndarray:
    """A state that saw the left face's column y = 0 (5 cells) occupied, the left space empty."""
    state = np.full(GEOMETRY.shape, -1, np.int8)
    state[0:2] = 0
    state[2, 0, :] = 1
    return state


def test_coverage_of_the_surface_facing_the_first_view() -> None:
    run = RunCoverage(wall_world(), GEOMETRY)
    # the seen column y = 0 lies within one cell of the left face's y = 0 and y = 1 columns: 10 of 25
    assert run(seen_column(), GEOMETRY, LEFT) == pytest.approx(10 / 25)
    assert run.surface is not None and run.surface.surface_count == 25
    more = seen_column()
    more[2, 4, :] = 1  # the y = 4 column too: y = 3 and 4 more, 20 of 25
    assert run(more, GEOMETRY, RIGHT) == pytest.approx(20 / 25)  # the first view fixed the surface


def test_the_first_view_on_the_other_side_sees_another_surface() -> None:
    # from the right the surface is the x = 4 plane: the x = 2 column is two cells away from it
    assert RunCoverage(wall_world(), GEOMETRY)(seen_column(), GEOMETRY, RIGHT) == 0.0


def test_a_first_view_outside_the_grid_or_inside_the_wall_measures_all_the_surface() -> None:
    for position in [(0.5, 2.25, 0.25), (1.35, 2.25, 0.25)]:  # left of the grid; in cell (3, 2, 2)
        run = RunCoverage(wall_world(), GEOMETRY)
        assert run(seen_column(), GEOMETRY, position) == pytest.approx(10 / 50)
        assert run.surface is not None and run.surface.surface_count == 50


def test_a_grid_placed_elsewhere_is_refused_by_name() -> None:
    run = RunCoverage(wall_world(), GEOMETRY)
    shifted = GridGeometry((1.1, 2.0, 0.0), 0.1, GEOMETRY.shape)
    with pytest.raises(ValueError, match="does not lie on the world's ground truth"):
        run(seen_column(), shifted, LEFT)
    with pytest.raises(ValueError, match="does not lie"):
        run(seen_column(), GridGeometry(GEOMETRY.origin, 0.05, GEOMETRY.shape), LEFT)
    with pytest.raises(ValueError, match="ground_truth: shape"):
        RunCoverage(np.zeros((2, 2, 2)), GEOMETRY)
    assert run.surface is None  # nothing measured yet


class Reports:
    """What a client releases: (item, coverage) in order; the grid at hand is ``self.grid``."""

    def __init__(self) -> None:
        self.released: list[tuple[str, float | None]] = []
        self.grid: tuple[np.ndarray, GridGeometry] | None = None
        self.loads = 0

    def release(self, item: str, coverage: float | None) -> None:
        self.released.append((item, coverage))

    def grid_at_hand(self) -> tuple[np.ndarray, GridGeometry] | None:
        self.loads += 1
        return self.grid


def two_grids() -> tuple[np.ndarray, np.ndarray]:
    """The grid after view 1 (the y = 0 column seen: 10 of 25) and after view 2 (y = 4 too: 20)."""
    first = seen_column()
    second = first.copy()
    second[2, 4, :] = 1
    second[5:7] = 0  # and the right space empty: another unknown fraction
    return first, second


def fraction(state: np.ndarray) -> float:
    return float(np.float32(np.mean(state == -1)))  # as an Explore feedback carries it


def test_a_report_that_comes_before_its_grid_waits_for_it() -> None:
    first, second = two_grids()
    reports = Reports()
    awaiting = ViewsAwaitingGrids(RunCoverage(wall_world(), GEOMETRY), reports.release)
    reports.grid = (first, GEOMETRY)
    awaiting.add("view 1", (fraction(first), np.array(LEFT)), reports.grid_at_hand)
    assert reports.released == [("view 1", pytest.approx(10 / 25))]  # its grid was at hand
    awaiting.add("view 2", (fraction(second), np.array(LEFT)), reports.grid_at_hand)
    awaiting.add("move failed", None, reports.grid_at_hand)  # no view: released in order, after view 2
    assert len(reports.released) == 1 and awaiting.waiting  # the grid at hand is view 1's
    reports.grid = (second, GEOMETRY)
    awaiting.offer(reports.grid_at_hand)
    assert reports.released[1:] == [("view 2", pytest.approx(20 / 25)), ("move failed", None)]
    assert not awaiting.waiting and awaiting.missed == 0


def test_a_view_whose_grid_never_comes_is_released_without_coverage_and_counted() -> None:
    first, second = two_grids()
    reports = Reports()
    awaiting = ViewsAwaitingGrids(RunCoverage(wall_world(), GEOMETRY), reports.release)
    awaiting.add("view 1", (fraction(first), np.array(LEFT)), reports.grid_at_hand)  # no grid yet
    assert reports.released == [] and reports.loads == 1
    reports.grid = (second, GEOMETRY)
    awaiting.add("view 2", (fraction(second), np.array(LEFT)), reports.grid_at_hand)  # view 1's grid passed
    assert reports.released == [("view 1", None), ("view 2", pytest.approx(20 / 25))]
    awaiting.add("view 3", (0.0, np.array(LEFT)), reports.grid_at_hand)
    awaiting.give_up()
    assert reports.released[-1] == ("view 3", None) and awaiting.missed == 2


def test_a_grid_off_the_world_turns_the_coverage_off() -> None:
    first, _ = two_grids()
    reports = Reports()
    awaiting = ViewsAwaitingGrids(RunCoverage(wall_world(), GEOMETRY), reports.release)
    reports.grid = (first, GridGeometry((0.0, 0.0, 0.0), 0.1, GEOMETRY.shape))
    awaiting.add("view 1", (fraction(first), np.array(LEFT)), reports.grid_at_hand)
    awaiting.add("view 2", (fraction(first), np.array(LEFT)), reports.grid_at_hand)
    assert reports.released == [("view 1", None), ("view 2", None)] and awaiting.missed == 0
    assert "does not lie on the world's ground truth" in awaiting.off
