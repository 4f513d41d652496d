"""From views ranked by gain to a view the arm can take: capability pruning, exact IK + collision
in gain order, and the motion cost.

Utility of a feasible view: ``gain − λ · L`` with ``L`` the joint-space length (Euclidean, radians
/ metres of the chain joints) of the straight path from the current configuration. With ``λ = 0``
the first feasible view in gain order wins (the paper's choice restricted to what the arm
reaches). With ``λ > 0`` candidates are checked in gain order until no remaining gain can beat
the best utility found (``utility ≤ gain``), so the result is the exact argmax over the ranked
list. A view is feasible when its pose has an IK solution within the limits, that configuration
is free of self- and grid collision, and the straight joint path to it is free at samples at most
``path_step`` rad apart, and again at :data:`VERIFY_STEP_RAD`. The cells the arm fills at the
current configuration count as free (it is there, so nothing else is; the map may hold them as
unknown or, unfiltered, occupied).
With a ``path_planner`` (:mod:`nbv_prob_cnn.arm.path_planning`), a goal whose straight path is
blocked gets a planned path instead, and ``L`` is that path's joint-space length.

The IK of the candidates is solved for blocks of upcoming candidates at once (4, then twice as
many each time up to 64; warm-started from the capability map's stored configurations), while
the checks still run and count in gain order: a view unreachable by IK costs about a tenth of a
one-by-one solve (``nbv bench --suite arm_loop``, docs/arm.md).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from nbv_prob_cnn.arm.capability import CapabilityMap
from nbv_prob_cnn.arm.collision import CollisionChecker, GridObstacles
from nbv_prob_cnn.arm.ik import (
    DEFAULT_IK,
    ROLL_HALF_TURN,
    IkResult,
    IkSettings,
    alternative_solutions,
    alternative_solutions_batch,
    solve_camera_poses,
)
from nbv_prob_cnn.arm.kinematics import CameraChain
from nbv_prob_cnn.arm.path_planning import JointPathPlanner, PathPlanningError, path_length
from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.basics.camera import matrix_from_quaternion, quaternion_from_matrix
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.planners import GainPlanner, PlanningContext, ViewChoice
from nbv_prob_cnn.planners.requests import view_pose

#: Candidates whose IK is solved together: the first block, and the largest (:class:`_IkAhead`).
#: A straight path free at ``path_step`` is checked again this finely (rad, per joint): a link can
#: cross a thin obstacle between two coarse samples (a unit test builds one between 0.1 rad samples),
#: as planned paths are checked again finely (``path_planning.VERIFY_DIVISOR``).
VERIFY_STEP_RAD = 0.005
IK_BLOCK_FIRST = 4
IK_BLOCK_MAX = 64


@dataclass
class ArmView:
    """A feasible view: the planner's choice, the joint goal, path length and utility;
    ``waypoints`` (``(k, nq)``, start to goal) when the path is a planned one, None when straight."""

    choice: ViewChoice
    q: np.ndarray
    path_length: float
    utility: float
    waypoints: np.ndarray | None = None
    roll_flipped: bool = False  # q takes the view turned 180° about the optical axis (same gain)


def reached_quaternion(view: ArmView, quaternion: np.ndarray) -> np.ndarray:
    """The optical frame's orientation (xyzw) the arm reaches for ``view`` planned with
    ``quaternion``: turned 180° about the optical axis when IK took the flipped pose."""
    if not view.roll_flipped:
        return np.asarray(quaternion, dtype=np.float64)
    return quaternion_from_matrix(matrix_from_quaternion(quaternion) @ ROLL_HALF_TURN[:3, :3])


def _seconds_text(seconds: dict[str, float]) -> str:
    """``"name 0.12, name 3.40"``: times (s) of named stages, for the log."""
    return ", ".join(f"{name} {value:.2f}" for name, value in seconds.items())


def _summed(a: dict[str, float], b: dict[str, float]) -> dict[str, float]:
    """Times (s) of named stages, added name by name (a name in one only keeps its time)."""
    return {name: a.get(name, 0.0) + b.get(name, 0.0) for name in {**a, **b}}


#: The counters of a :class:`FeasibilityReport` (views per stage), summed over the passes by
#: :meth:`~FeasibilityReport.total`.
_COUNTERS = ("ranked", "candidates", "camera_blocked", "checked", "unreachable", "in_collision", "path_blocked",
             "paths_planned", "paths_not_found")  # fmt: skip


@dataclass
class FeasibilityReport:
    """Outcome of :meth:`ArmFeasibility.select`: the chosen view (None if none is feasible),
    counters (ranked views, candidates left by the capability map, exact checks and why they
    failed) and times (seconds) of the stages.

    A near-camera fallback (:meth:`~nbv_prob_cnn.arm.selection.ArmViewSelector.select`) ranks and
    checks twice: its report is the second pass's own, with the first in ``first_pass``;
    :meth:`total` is what the whole plan counted and took, :meth:`fallback_text` what the first
    pass found."""

    view: ArmView | None
    ranked: int = 0
    candidates: int = 0
    camera_blocked: int = 0
    checked: int = 0
    unreachable: int = 0
    in_collision: int = 0
    path_blocked: int = 0
    budget_exhausted: bool = False
    fallback: bool = False  # set by callers that ranked again with a narrower origin filter
    #: with ``fallback``: the report of the first pass (the wider filter), which found no view
    first_pass: FeasibilityReport | None = None
    paths_planned: int = 0  # straight path blocked, a planned path found (``path_planner``)
    paths_not_found: int = 0  # straight path blocked, path planning failed too
    times: dict[str, float] = field(default_factory=lambda: {"capability": 0.0, "ik_collision": 0.0})
    #: parts of ``times["ik_collision"]`` (s): ``ik`` (first solutions), ``alternatives`` (other
    #: solutions of views whose first collides), ``collision`` (goal and straight-path checks)
    parts: dict[str, float] = field(default_factory=dict)
    #: stages of the planned paths' time (s, summed over paths: ``endpoints``, ``solve``,
    #: ``simplify``, ``verify``, see :meth:`JointPathPlanner.plan`)
    path_stages: dict[str, float] = field(default_factory=dict)
    path_length_rad: float = 0.0  # joint length of the planned paths, summed

    def add_time(self, stage: str, since: float) -> None:
        """Add the time from ``since`` (``time.perf_counter()``) until now to ``parts[stage]``."""
        self.parts[stage] = self.parts.get(stage, 0.0) + time.perf_counter() - since

    def total(self) -> FeasibilityReport:
        """The whole plan: with ``first_pass`` (a fallback), both passes in one report (the
        counters, ``times``, ``parts``, ``path_stages`` and ``path_length_rad`` summed; the view
        and ``fallback`` of this, the last, pass; ``budget_exhausted`` when either pass spent the
        budget; no ``first_pass``); without, this report itself."""
        if self.first_pass is None:
            return self
        first = self.first_pass.total()
        return FeasibilityReport(
            self.view,
            **{name: getattr(first, name) + getattr(self, name) for name in _COUNTERS},
            budget_exhausted=first.budget_exhausted or self.budget_exhausted,
            fallback=self.fallback,
            times=_summed(first.times, self.times),
            parts=_summed(first.parts, self.parts),
            path_stages=_summed(first.path_stages, self.path_stages),
            path_length_rad=first.path_length_rad + self.path_length_rad,
        )

    def fallback_text(self) -> str:
        """What the first pass of a fallback found, for a log line: ``"fallback after 300 checked:
        300 in collision, 673 camera-blocked skipped"`` (its failures, then ``check budget spent``
        when it was; ranked views and candidates when it checked none); ``""`` without
        ``first_pass``. No parentheses: the view line's note (``view 3 (...)``) ends at one."""
        first = self.first_pass
        if first is None:
            return ""
        found = [f"{count} {what}" for count, what in ((first.unreachable, "unreachable"),
                 (first.in_collision, "in collision"), (first.path_blocked, "path blocked"),
                 (first.camera_blocked, "camera-blocked skipped")) if count]  # fmt: skip
        if first.budget_exhausted:
            found.append("check budget spent")
        if not first.checked and not first.camera_blocked:
            found.append(f"{first.ranked} ranked, {first.candidates} candidates")
        return f"fallback after {first.checked} checked: {', '.join(found)}"

    def summary(self) -> str:
        """One log line: the counters and the parts of the IK + collision time (a fallback: each
        pass's own, the first pass's first)."""
        seconds = {**self.parts, **{k: v for k, v in self.times.items() if k == "path_planning"}}
        parts = _seconds_text(seconds)
        paths = f" (path: {_seconds_text(self.path_stages)}; length {self.path_length_rad:.2f} rad)"
        first = "" if self.first_pass is None else f"{self.first_pass.summary()}, no view; near the camera: "
        return first + (
            f"{self.checked} checked of {self.candidates} candidates ({self.camera_blocked} camera-blocked skipped, "
            f"{self.unreachable} unreachable, {self.in_collision} in collision, {self.path_blocked} path blocked; "
            f"paths planned {self.paths_planned}, not found {self.paths_not_found}); s: {parts or 'none'}"
            + (paths if self.paths_planned else "")
        )


class ArmFeasibility:
    """The arm's view of a plan: capability pruning and the exact check of ranked views.

    Args:
        robot: robot model; ``checker`` (grid-collision sample spacing ~ cell size) and ``chain``
            are built from it.
        capability: optional capability map (pruning before the gain).
        motion_weight: ``λ`` of the utility (0 = the paper's behaviour).
        path_step: joint-space sampling step (rad) of the straight path check.
        margin_cells: growth of the blocked cells for grid collision.
        free_above_m: optional tabletop prior, see :meth:`GridObstacles.from_state` (None: every
            unknown cell blocks).
        max_checks: at most this many candidates get the exact check per call (bounds the time
            when the ranked views are mostly infeasible); 0 = no limit.
        rng: random restarts of IK.
        ik_alternatives: when the first IK solution of a view collides (or its path does), up to
            this many other solutions of the same pose (:func:`alternative_solutions`) are
            checked before the view is rejected; 0 = the first solution only.
        strict_capability: views pass the capability map only when every lattice node around
            their cell reaches the orientation (:meth:`CapabilityMap.views_at` ``strict``).
        path_planner: when the straight path to a collision-free goal is blocked, plan one
            (:class:`JointPathPlanner`, at most ``settings.max_attempts`` per :meth:`select`);
            the motion cost is then the planned path's length. None: straight paths only.
        roll_symmetric: a view turned 180° about its optical axis counts as the view itself (the
            frustum covers the same cells, so the gain is the same): IK also solves that pose
            from the current configuration and the nearer solution wins (wrist turns of up to
            π saved); the chosen view's ``roll_flipped`` says which.
    """

    def __init__(
        self,
        robot: RobotModel,
        checker: CollisionChecker,
        capability: CapabilityMap | None = None,
        motion_weight: float = 0.0,
        path_step: float = 0.1,
        margin_cells: int = 0,
        free_above_m: float | None = None,
        max_checks: int = 0,
        ik_settings: IkSettings = DEFAULT_IK,
        rng: np.random.Generator | None = None,
        ik_alternatives: int = 0,
        strict_capability: bool = False,
        path_planner: JointPathPlanner | None = None,
        roll_symmetric: bool = False,
    ) -> None:
        if not (np.isfinite(motion_weight) and motion_weight >= 0):
            raise ValueError(f"motion_weight: expected a finite value >= 0, got {motion_weight}")
        if not (np.isfinite(path_step) and path_step > 0):
            raise ValueError(f"path_step: expected a positive step in rad, got {path_step}")
        self.robot = robot
        self.chain = CameraChain(robot)
        self.checker = checker
        self.capability = capability
        self.motion_weight = float(motion_weight)
        self.path_step = float(path_step)
        self.margin_cells = int(margin_cells)
        self.free_above_m = free_above_m
        if max_checks < 0:
            raise ValueError(f"max_checks: expected >= 0 (0 = no limit), got {max_checks}")
        self.max_checks = int(max_checks)
        self.ik_settings = ik_settings
        if ik_alternatives < 0:
            raise ValueError(f"ik_alternatives: expected >= 0, got {ik_alternatives}")
        self.ik_alternatives = int(ik_alternatives)
        self.strict_capability = bool(strict_capability)
        self.path_planner = path_planner
        self.roll_symmetric = bool(roll_symmetric)
        self.rng = rng if rng is not None else np.random.default_rng()

    def origin_filter(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """Origin filter for ``GainPlanner.rank`` (None without a capability map)."""
        return self.capability.origin_filter if self.capability is not None else None

    def view_mask(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """Orientations possibly reachable per origin, for ``GainPlanner.rank`` (None without a
        capability map): the ranked list then holds only (cell, orientation) pairs the map keeps."""
        if self.capability is None:
            return None
        return self.capability.strict_views_at if self.strict_capability else self.capability.views_at

    def prune(self, ranked: Sequence[ViewChoice]) -> list[ViewChoice]:
        """The ranked views whose (cell, orientation) the capability map says may be reachable."""
        if self.capability is None or not ranked:
            return list(ranked)
        cells = np.array([c.cell for c in ranked])
        views = np.array([c.view_index for c in ranked])
        keep = self.capability.views_at(cells, self.strict_capability)[np.arange(len(ranked)), views]
        return [c for c, k in zip(ranked, keep, strict=True) if k]

    def _goals(
        self,
        first: np.ndarray,
        target: np.ndarray,
        current_q: np.ndarray,
        alternatives: Callable[[], list[IkResult]] | None = None,
    ) -> Iterator[np.ndarray]:
        """``first``, then (computed only if asked for, by ``alternatives`` when given) up to
        ``ik_alternatives`` other IK solutions of ``target``, closest to ``current_q`` first."""
        yield first
        if self.ik_alternatives:
            if alternatives is not None:
                others = alternatives()
            else:
                others = alternative_solutions(self.chain, target, current_q, self.rng, self.ik_settings)
            distinct = [r.q for r in others if r.q is not None and np.abs(r.q - first).max() > 1e-3]
            yield from distinct[: self.ik_alternatives]

    def straight_path_free(self, q_start: np.ndarray, q_goal: np.ndarray, obstacles: GridObstacles) -> bool:
        """The straight joint path is free at ``path_step`` (cheap; most blocked paths fail here) and
        again at :data:`VERIFY_STEP_RAD`."""
        check = self.checker.path_is_free
        return check(q_start, q_goal, obstacles, self.path_step) and (
            self.path_step <= VERIFY_STEP_RAD or check(q_start, q_goal, obstacles, VERIFY_STEP_RAD)
        )

    def _free_goal(
        self,
        first: np.ndarray,
        target: np.ndarray,
        current_q: np.ndarray,
        obstacles: GridObstacles,
        report: FeasibilityReport | None = None,
        alternatives: Callable[[], list[IkResult]] | None = None,
    ) -> tuple[np.ndarray | None, str, np.ndarray | None]:
        """The first of :meth:`_goals` that is collision-free with a free straight path from
        ``current_q``; else, with a ``path_planner``, the first collision-free goal with a planned
        path (its waypoints third); else None and why the last one failed (``"collision"`` or
        ``"path"``)."""
        failure = ""
        blocked: np.ndarray | None = None  # the first collision-free goal whose straight path is blocked
        goals = self._goals(first, target, current_q, alternatives)
        while True:
            begin = time.perf_counter()
            goal = next(goals, None)  # the alternatives are solved when first asked for
            if report is not None and goal is not first:
                report.add_time("alternatives", begin)
            if goal is None:
                break
            begin = time.perf_counter()
            if not self.checker.is_free(goal, obstacles):
                failure = "collision"
            elif not self.straight_path_free(current_q, goal, obstacles):
                failure = "path"
                blocked = goal if blocked is None else blocked
            else:
                failure = ""
            if report is not None:
                report.add_time("collision", begin)
            if not failure:
                return goal, "", None
        planner = self.path_planner
        if blocked is not None and planner is not None and report is not None:
            if report.paths_planned + report.paths_not_found < planner.settings.max_attempts:
                begin = time.perf_counter()
                try:
                    path = planner.plan(current_q, blocked, obstacles)
                except PathPlanningError:
                    report.paths_not_found += 1
                else:
                    report.paths_planned += 1
                    for stage, seconds in path.stages.items():
                        report.path_stages[stage] = report.path_stages.get(stage, 0.0) + seconds
                    report.path_length_rad += path.length
                    return blocked, "", path.waypoints
                finally:
                    report.times["path_planning"] = report.times.get("path_planning", 0.0) + time.perf_counter() - begin
            failure = "path"
        return None, failure, None

    def select(
        self,
        ranked: Sequence[ViewChoice],
        state: np.ndarray,
        context: PlanningContext,
        geometry: GridGeometry,
        current_q: np.ndarray,
    ) -> FeasibilityReport:
        """The best feasible view of ``ranked`` (best gain first), see the module doc.

        Raises:
            ValueError: bad configuration or grid.
        """
        current_q = self.robot.check_q(current_q, "current_q")
        report = FeasibilityReport(None)
        start = time.perf_counter()
        candidates = self.prune(ranked)
        report.ranked, report.candidates = len(ranked), len(candidates)
        report.times["capability"] = time.perf_counter() - start
        start = time.perf_counter()
        obstacles = GridObstacles.from_state(state, geometry, self.margin_cells, self.free_above_m)
        obstacles = obstacles.cleared(self.checker.body_points(current_q))
        camera_rigid = self.checker.camera_rigid_points(current_q)
        best: ArmView | None = None
        ahead = _IkAhead(self, candidates, context, geometry, current_q, obstacles, camera_rigid)
        for index, choice in enumerate(candidates):
            if best is not None and (self.motion_weight == 0.0 or choice.gain <= best.utility):
                break
            if ahead.blocked(index):
                report.camera_blocked += 1  # exact for these bodies and cheap: no IK, no budget
                continue
            if self.max_checks and report.checked >= self.max_checks:
                report.budget_exhausted = True
                break
            report.checked += 1
            remaining = self.max_checks - report.checked + 1 if self.max_checks else len(candidates)
            begin = time.perf_counter()
            solution = ahead.solution(index, remaining)
            report.add_time("ik", begin)
            target = ahead.targets[index]
            if solution.q is None:
                report.unreachable += 1
                continue
            goal, failure, waypoints = self._free_goal(
                solution.q, target, current_q, obstacles, report, functools.partial(ahead.alternatives, index)
            )
            if goal is None:
                if failure == "collision":
                    report.in_collision += 1
                else:
                    report.path_blocked += 1
                continue
            length = float(np.linalg.norm((goal - current_q)[self.chain.q_index]))
            if waypoints is not None:  # a planned path: its own length is the motion cost
                length = path_length(waypoints, self.chain.q_index)
            utility = choice.gain - self.motion_weight * length
            if best is None or utility > best.utility:
                best = ArmView(choice, goal, length, utility, waypoints, solution.roll_flipped and goal is solution.q)
        report.view = best
        report.times["ik_collision"] = time.perf_counter() - start
        return report


class _IkAhead:
    """The candidates' camera-rigid check and IK, computed for blocks of upcoming candidates at
    once (:func:`solve_camera_poses`), in gain order: the first block is small (the first
    candidate is often feasible), each next one twice as large up to :data:`IK_BLOCK_MAX`.
    Warm seeds come from the capability map's stored configurations. Blocks never reach past
    the check budget."""

    def __init__(self, arm: ArmFeasibility, candidates, context, geometry, current_q, obstacles, camera_rigid) -> None:
        self.arm, self.candidates, self.current_q = arm, candidates, current_q
        self.context, self.geometry = context, geometry
        self.obstacles, self.camera_rigid = obstacles, camera_rigid
        self.targets: dict[int, np.ndarray] = {}
        self._blocked: dict[int, bool] = {}
        self._solved: dict[int, IkResult] = {}
        self._alternatives: dict[int, list[IkResult]] = {}
        self._block = self._alt_block = IK_BLOCK_FIRST

    def blocked(self, index: int) -> bool:
        """Whether a camera-rigid body (hand, fingers) of candidate ``index`` enters a blocked cell."""
        if index not in self._blocked:
            position, quaternion = view_pose(self.candidates[index], self.context, self.geometry)
            target = np.eye(4)
            target[:3, :3] = matrix_from_quaternion(quaternion)
            target[:3, 3] = position
            self.targets[index] = target
            points = self.camera_rigid @ target[:3, :3].T + position
            self._blocked[index] = bool(np.any(self.obstacles.hits(points)))
        return self._blocked[index]

    def solution(self, index: int, budget: int) -> IkResult:
        """The IK result of candidate ``index`` (not camera-blocked); solves it with up to
        ``budget`` - 1 of the next candidates that are not camera-blocked."""
        if index not in self._solved:
            block, later = [index], index + 1
            while len(block) < min(self._block, max(1, budget)) and later < len(self.candidates):
                if not self.blocked(later):
                    block.append(later)
                later += 1
            self._block = min(2 * self._block, IK_BLOCK_MAX)
            arm = self.arm
            warm = None
            if arm.capability is not None:
                cells = np.array([self.candidates[i].cell for i in block])
                views = np.array([self.candidates[i].view_index for i in block])
                warm = arm.capability.seed_configurations(cells, views)
            targets = np.stack([self.targets[i] for i in block])
            results = solve_camera_poses(
                arm.chain, targets, self.current_q, arm.rng, arm.ik_settings, warm, arm.roll_symmetric
            )
            self._solved.update(zip(block, results, strict=True))
        return self._solved[index]

    def alternatives(self, index: int) -> list[IkResult]:
        """:func:`alternative_solutions` of candidate ``index`` (whose first IK solution failed a
        check), solved together with those of the next already-solved candidates whose first
        solution collides (they would ask for theirs next)."""
        if index not in self._alternatives:
            arm = self.arm
            block, later = [index], index + 1
            while len(block) < self._alt_block and later in self._blocked:
                if not self._blocked[later]:
                    if later not in self._solved:
                        break
                    q = self._solved[later].q
                    if q is not None and not arm.checker.is_free(q, self.obstacles):
                        block.append(later)
                later += 1
            self._alt_block = min(2 * self._alt_block, IK_BLOCK_MAX)
            targets = np.stack([self.targets[i] for i in block])
            found = alternative_solutions_batch(arm.chain, targets, self.current_q, arm.rng, arm.ik_settings)
            self._alternatives.update(zip(block, found, strict=True))
        return self._alternatives[index]


def takes_view_mask(planner) -> bool:
    """Whether ``planner.rank`` takes a ``view_mask``: a ``GainPlanner``, or a wrapper that says so
    (``takes_view_mask`` attribute true)."""
    return isinstance(planner, GainPlanner) or bool(getattr(planner, "takes_view_mask", False))


def plan_with_arm(
    planner,
    state: np.ndarray,
    context: PlanningContext,
    geometry: GridGeometry,
    arm: ArmFeasibility,
    current_q: np.ndarray,
    top_k: int = 50,
    origin_filter: Callable[[np.ndarray], np.ndarray] | None = None,
    view_mask: Callable[[np.ndarray], np.ndarray] | None = None,
) -> FeasibilityReport:
    """Thin adapter: ``planner.rank`` (a ``GainPlanner``) on the capability-filtered origins, with
    the map's orientations as view mask (a ``GainPlanner``'s local search: only (cell, orientation)
    pairs the map keeps are ranked), then :meth:`ArmFeasibility.select`. Times: ``gain`` (the
    planner, pruning excluded), ``capability`` (origin filter, view mask and view pruning),
    ``ik_collision`` (the exact stage). ``origin_filter`` (optional) narrows the origins
    further, before the capability map's filter; ``view_mask`` (optional) is ANDed with the
    map's (a ``GainPlanner``'s local search), and the ranked views it forbids are dropped
    afterwards too (planners without view masks, remote rankers)."""
    pruning = 0.0

    def timed(stage: Callable[[np.ndarray], np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
        def run(cells: np.ndarray) -> np.ndarray:
            nonlocal pruning
            begin = time.perf_counter()
            out = stage(cells)
            pruning += time.perf_counter() - begin
            return out

        return run

    reachable = arm.origin_filter() or (lambda origins: origins)
    extra = origin_filter

    def origins_kept(origins: np.ndarray) -> np.ndarray:
        return reachable(extra(origins) if extra is not None else origins)

    mapped = arm.view_mask()
    extra_mask = view_mask

    def views_kept(origins: np.ndarray) -> np.ndarray:
        allowed = (
            mapped(origins) if mapped is not None else np.ones((origins.shape[0], len(context.orientations)), bool)
        )
        return allowed & extra_mask(origins) if extra_mask is not None else allowed

    start = time.perf_counter()
    kept = timed(origins_kept)
    if takes_view_mask(planner) and (mapped is not None or extra_mask is not None):
        ranked = planner.rank(state, context, top_k=top_k, origin_filter=kept, view_mask=timed(views_kept))
    else:
        ranked = planner.rank(state, context, top_k=top_k, origin_filter=kept)
    gain_seconds = time.perf_counter() - start - pruning
    if extra_mask is not None and ranked:  # a remote ranker, or a planner without view masks, ignored it
        begin = time.perf_counter()
        cells = np.array([c.cell for c in ranked])
        allowed = np.asarray(extra_mask(cells), dtype=bool)[np.arange(len(ranked)), [c.view_index for c in ranked]]
        ranked = [c for c, keep in zip(ranked, allowed, strict=True) if keep]
        pruning += time.perf_counter() - begin
    report = arm.select(ranked, state, context, geometry, current_q)
    report.times["gain"] = gain_seconds
    report.times["capability"] += pruning
    return report
