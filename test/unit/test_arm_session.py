"""The arm's bookkeeping between plans and moves (ArmSession), without ROS or a robot model: a
stand-in arm whose only body point sits at (q0, q1, q2) metres, so every swept cell is known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.arm.arm_session import SWEPT_STEP, ArmBookkeepingMover, ArmSession, unreachable_message
from nbv_prob_cnn.arm.feasibility import ArmView, FeasibilityReport
from nbv_prob_cnn.arm.selection import ArmViewSelector
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.session import MoveError, PlannedView
from nbv_prob_cnn.planners import ViewChoice

GEOMETRY = GridGeometry((0.0, 0.0, 0.0), 0.1, (10, 10, 10))


class PointRobot:
    def check_q(self, q, name):
        return np.asarray(q, dtype=np.float64)


class PointChecker:
    """One body point at the configuration itself (metres)."""

    robot = PointRobot()

    def body_points(self, q):
        return np.asarray(q, dtype=np.float64).reshape(1, 3)


class PointArm:
    checker = PointChecker()
    robot = checker.robot


class PointSetup:
    robot = PointRobot()

    def __init__(self) -> None:
        self.built: list[GridGeometry] = []

    def feasibility(self, geometry):
        self.built.append(geometry)
        return PointArm()


def free_cells(session: ArmSession) -> set[tuple[int, ...]]:
    (selector, _), *_ = session._selectors.values()
    return {tuple(int(v) for v in c) for c in np.argwhere(selector.swept.free)}


def cell_q(i: int, j: int = 0, k: int = 0) -> np.ndarray:
    """The configuration whose body point lies at the centre of cell (i, j, k)."""
    return (np.array([i, j, k], dtype=np.float64) + 0.5) * 0.1


def test_configurations_seen_are_kept_one_swept_step_apart_and_carved_at_the_next_plan():
    session = ArmSession(PointSetup(), carve_swept=True)
    session.saw_configuration(cell_q(0))
    session.saw_configuration(cell_q(0) + SWEPT_STEP / 2)  # too close: dropped
    session.saw_configuration(cell_q(1))
    assert len(session._seen) == 2
    session.set_up(GEOMETRY)
    assert free_cells(session) == {(0, 0, 0), (1, 0, 0)}
    session.saw_configuration(cell_q(4))
    assert free_cells(session) == {(0, 0, 0), (1, 0, 0)}  # not before the next plan or move
    session.set_up(GEOMETRY)
    assert free_cells(session) == {(0, 0, 0), (1, 0, 0), (4, 0, 0)}
    assert len(session.setup.built) == 1  # one selector per geometry


def test_without_carving_nothing_is_swept():
    session = ArmSession(PointSetup(), carve_swept=False)
    session.saw_configuration(cell_q(0))
    session.set_up(GEOMETRY)
    (selector, _), *_ = session._selectors.values()
    assert session._seen == [] and selector.swept is None


def test_set_up_is_claimed_once_per_3d_geometry():
    session = ArmSession(PointSetup())
    assert session.claim_set_up(GEOMETRY) and not session.claim_set_up(GEOMETRY)
    assert session.claim_set_up(GridGeometry((0.0, 0.0, 0.0), 0.05, (10, 10, 10)))
    assert not session.claim_set_up(GridGeometry((0.0, 0.0, 0.0), 1.0, (10, 10)))  # the arm plans in 3D only


@pytest.fixture
def planned(monkeypatch):
    """A session whose selector always plans the view at cell (3, 0, 0), orientation 5, with the
    joint goal cell_q(3)."""
    choice = ViewChoice(np.array([3, 0, 0]), 5, 1.0)
    view = ArmView(choice, cell_q(3), 0.2, 0.8)
    monkeypatch.setattr(ArmViewSelector, "select", lambda self, *args: FeasibilityReport(view=view))
    session = ArmSession(PointSetup(), carve_swept=True)
    report = session.select(None, np.full(GEOMETRY.shape, -1, np.int8), None, GEOMETRY, cell_q(0), 10)
    assert report.view is view
    return session, view


def test_a_move_of_the_arm_sweeps_its_path_and_takes_the_view(planned):
    session, view = planned
    q_start, planned_view = session.planned_move()
    np.testing.assert_array_equal(q_start, cell_q(0))
    assert planned_view is view
    session.took_planned_view(arm_moved=True)
    (selector, _), *_ = session._selectors.values()
    # the straight path from cell 0 to cell 3 along x, sampled every 0.02 m: cells 0..3
    assert free_cells(session) == {(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)}
    assert selector.taken == {((3, 0, 0), 5)} and session.planned_move() is None


def test_a_camera_move_only_takes_the_view(planned):
    session, _ = planned
    session.took_planned_view(arm_moved=False)
    (selector, _), *_ = session._selectors.values()
    assert free_cells(session) == set() and selector.taken == {((3, 0, 0), 5)}


def test_the_bookkeeping_mover_rules_a_failed_view_out_and_takes_a_reached_one(planned):
    session, _ = planned

    class Mover:
        def __init__(self, fail):
            self.fail = fail

        def move(self, planned_view, interrupt):
            if self.fail:
                raise MoveError("arm stalled")
            return 42

    target = PlannedView("view", 1.0)
    with pytest.raises(MoveError, match="arm stalled"):
        ArmBookkeepingMover(Mover(True), session, arm_moves=True).move(target, Interrupt())
    (selector, _), *_ = session._selectors.values()
    assert selector.taken == {((3, 0, 0), 5)} and free_cells(session) == set()  # ruled out, nothing swept
    assert session.planned_move() is None
    session.select(None, np.full(GEOMETRY.shape, -1, np.int8), None, GEOMETRY, cell_q(0), 10)
    assert ArmBookkeepingMover(Mover(False), session, arm_moves=True).move(target, Interrupt()) == 42
    assert free_cells(session) == {(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)}


def test_unreachable_message_counts_the_exact_stage():
    report = FeasibilityReport(view=None, checked=30, unreachable=4, in_collision=25, path_blocked=1,
                               budget_exhausted=True, fallback=True)  # fmt: skip
    assert unreachable_message(report) == (
        "no view the arm reaches collision-free: 30 ranked views checked (4 without IK solution, 25 in collision, "
        "1 with a blocked path, check budget spent, near the camera too)"
    )


def test_the_check_summary_shows_the_first_pass_before_the_near_camera_one():
    first = FeasibilityReport(view=None, ranked=900, candidates=800, checked=300, camera_blocked=673, in_collision=300,
                              budget_exhausted=True)  # fmt: skip
    first.parts = {"ik": 2.44, "collision": 2.26}
    near = FeasibilityReport(view=None, ranked=40, candidates=40, checked=1, fallback=True, first_pass=first)
    near.parts = {"ik": 0.11}
    assert near.summary() == (
        "300 checked of 800 candidates (673 camera-blocked skipped, 0 unreachable, 300 in collision, 0 path blocked; "
        "paths planned 0, not found 0); s: ik 2.44, collision 2.26, no view; near the camera: "
        "1 checked of 40 candidates (0 camera-blocked skipped, 0 unreachable, 0 in collision, 0 path blocked; "
        "paths planned 0, not found 0); s: ik 0.11"
    )
