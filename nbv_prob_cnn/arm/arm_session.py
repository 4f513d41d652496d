"""The arm's bookkeeping across the plans and moves of a planner that runs beside a robot (the ROS
``nbv_planner`` with ``use_arm``), with no ROS here.

* One :class:`~nbv_prob_cnn.arm.selection.ArmViewSelector` per grid geometry, set up once (the
  capability map and the collision model take seconds to load or build: :meth:`ArmSession.claim_set_up`
  lets a caller start that in the background when a grid of a new geometry arrives).
* The configurations seen on ``joint_states`` (:meth:`ArmSession.saw_configuration`, kept one
  :data:`SWEPT_STEP` apart) are carved free in each selector's swept volume before the next plan.
* The last plan's view: :meth:`ArmSession.took_planned_view` after the move (its joint path swept
  when the arm moved there, the view taken), :meth:`ArmSession.rule_out_planned_view` after a failed
  one (never planned again), :meth:`ArmSession.planned_move` for the trajectory to send.
* :class:`ArmBookkeepingMover` does the last two around any mover of an exploration session.

Arm planning runs one plan at a time (one lock, held for the whole selection); the configurations
seen have a lock of their own, so that the joint-state callback never waits for a plan.
"""

from __future__ import annotations

import threading

import numpy as np

from nbv_prob_cnn.arm.feasibility import ArmView, FeasibilityReport
from nbv_prob_cnn.arm.selection import ArmViewSelector
from nbv_prob_cnn.arm.swept import SweptVolume
from nbv_prob_cnn.arm.views import ArmPlanningSetup
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.session import MoveError, Mover, PlannedView, TargetT
from nbv_prob_cnn.planners import PlanningContext

#: Joint-space step (rad) between the configurations whose bodies are carved free (joint_states
#: samples kept, samples of a commanded path), as ``SweptVolume``'s default.
SWEPT_STEP = 0.02
#: Planning's message (prefix) when no view is one the arm can take (an end of an exploration).
NO_REACHABLE_VIEW = "no view the arm reaches collision-free"

#: A grid geometry as a dictionary key: origin, resolution, shape.
GeometryKey = tuple[tuple[float, ...], float, tuple[int, ...]]


def geometry_key(geometry: GridGeometry) -> GeometryKey:
    return tuple(float(v) for v in geometry.origin), float(geometry.resolution), tuple(int(n) for n in geometry.shape)


class ArmSession:
    """The arm's state between plans (see the module docstring).

    Args:
        setup: the robot and how views are checked.
        carve_swept: count the cells the arm's bodies filled (configurations seen, paths moved) as free.
        fallback_radius_m: the selectors' near-camera fallback (0: off).
    """

    def __init__(self, setup: ArmPlanningSetup, carve_swept: bool = True, fallback_radius_m: float = 0.0) -> None:
        self.setup, self.robot = setup, setup.robot
        self.carve_swept, self.fallback_radius_m = carve_swept, fallback_radius_m
        self._lock = threading.Lock()  # guards the selectors and the last plan (one plan at a time)
        self._selectors: dict[GeometryKey, tuple[ArmViewSelector, list[int]]] = {}  # selector, configurations fed
        self._last_plan: tuple[ArmViewSelector, np.ndarray, ArmView] | None = None  # selector, start, view
        self._seen_lock = threading.Lock()  # guards the two below (a plan holds _lock for long)
        self._seen: list[np.ndarray] = []  # configurations seen, >= one swept step apart
        self._claimed: set[GeometryKey] = set()  # geometries whose set-up a caller started

    def saw_configuration(self, q: np.ndarray) -> None:
        """A configuration seen on joint_states: kept when it lies one swept step from the last kept
        (and ``carve_swept``)."""
        if not self.carve_swept:
            return
        with self._seen_lock:
            if not self._seen or np.abs(q - self._seen[-1]).max() >= SWEPT_STEP:
                self._seen.append(np.array(q, dtype=np.float64))

    def claim_set_up(self, geometry: GridGeometry) -> bool:
        """Whether the caller should set up this geometry now (:meth:`set_up`): True once per 3D geometry."""
        key = geometry_key(geometry)
        with self._seen_lock:
            if key in self._claimed or geometry.dims != 3:
                return False
            self._claimed.add(key)
            return True

    def set_up(self, geometry: GridGeometry) -> None:
        """Load or build this geometry's capability map and collision model (waits for a plan that runs).

        Raises:
            ValueError: e.g. an arm that reaches nothing of this grid.
        """
        with self._lock:
            self._selector(geometry)

    def select(
        self,
        planner,
        state: np.ndarray,
        context: PlanningContext,
        geometry: GridGeometry,
        current_q: np.ndarray,
        top_k: int,
    ) -> FeasibilityReport:
        """The view the arm takes next from ``current_q`` (:meth:`ArmViewSelector.select`), kept as
        the planned view (none when ``report.view`` is None)."""
        with self._lock:
            selector = self._selector(geometry)
            report = selector.select(planner, state, context, current_q, top_k)
            self._last_plan = None if report.view is None else (selector, np.array(current_q), report.view)
        return report

    def planned_move(self) -> tuple[np.ndarray, ArmView] | None:
        """The last plan's start configuration and view (None: no plan, or it was taken or ruled out)."""
        with self._lock:
            plan = self._last_plan
        return None if plan is None else (plan[1], plan[2])

    def took_planned_view(self, arm_moved: bool) -> None:
        """The camera is at the last plan's view: it is taken; when the arm moved there
        (``arm_moved``), its joint path is swept too, and so are the configurations seen meanwhile
        (now, while the exploration waits for a grid, not in the next plan)."""
        with self._lock:
            if self._last_plan is None:
                return
            selector, q_start, view = self._last_plan
            if arm_moved:
                selector.moved(q_start, view)
            else:
                selector.take(view.choice)
            self._last_plan = None
            for swept_by, fed in self._selectors.values():
                if swept_by is selector:
                    self._sweep_seen(selector, fed)

    def rule_out_planned_view(self) -> None:
        """The move to the last plan's view failed: never plan that view again."""
        with self._lock:
            if self._last_plan is not None:
                selector, _, view = self._last_plan
                selector.take(view.choice)
                self._last_plan = None

    def _selector(self, geometry: GridGeometry) -> ArmViewSelector:
        """The selector of this geometry, its swept volume brought up to date (``_lock`` held)."""
        key = geometry_key(geometry)
        if key not in self._selectors:
            arm = self.setup.feasibility(geometry)
            swept = SweptVolume(arm.checker, geometry, SWEPT_STEP) if self.carve_swept else None
            self._selectors[key] = (ArmViewSelector(arm, geometry, swept, self.fallback_radius_m), [0])
        selector, fed = self._selectors[key]
        self._sweep_seen(selector, fed)
        return selector

    def _sweep_seen(self, selector: ArmViewSelector, fed: list[int]) -> None:
        """Add the configurations seen since the last call to the selector's swept volume
        (``fed[0]``: how many it has had; ``_lock`` held)."""
        if selector.swept is None:
            return
        with self._seen_lock:
            seen = self._seen[fed[0] :]
        for q in seen:
            selector.swept.add_configuration(q)
        fed[0] += len(seen)


class ArmBookkeepingMover(Mover[TargetT]):
    """A mover of an exploration session that keeps ``arm`` up to date: the planned view is taken
    after a move (swept when ``arm_moves``: the arm itself moved there), ruled out after a failed one."""

    def __init__(self, mover: Mover[TargetT], arm: ArmSession, arm_moves: bool) -> None:
        self.mover, self.arm, self.arm_moves = mover, arm, arm_moves

    def move(self, planned: PlannedView[TargetT], interrupt: Interrupt) -> int:
        try:
            stamp_ns = self.mover.move(planned, interrupt)
        except MoveError:
            self.arm.rule_out_planned_view()
            raise
        self.arm.took_planned_view(self.arm_moves)
        return stamp_ns


def unreachable_message(report: FeasibilityReport) -> str:
    """Why arm-constrained planning found no view, with the counts of the exact stage (a fallback:
    both passes, :meth:`FeasibilityReport.total`)."""
    report = report.total()
    budget = ", check budget spent" if report.budget_exhausted else ""
    budget += ", near the camera too" if report.fallback else ""
    return (
        f"{NO_REACHABLE_VIEW}: {report.checked} ranked views checked ({report.unreachable} without IK solution, "
        f"{report.in_collision} in collision, {report.path_blocked} with a blocked path{budget})"
    )
