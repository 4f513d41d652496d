"""Collision-free joint paths that are not straight: OMPL's RRTConnect in the camera chain's joint
space, then OMPL's path simplifier.

A configuration is valid when it lies within the joint limits, has no self-collision and no
moving body enters an occupied or unknown cell (:meth:`CollisionChecker.is_free`, the same check
as the straight paths of :class:`~nbv_prob_cnn.arm.feasibility.ArmFeasibility`). Motions between
two states are checked by OMPL's discrete motion validator at samples at most
:attr:`PathPlannerSettings.resolution_rad` apart (Euclidean joint-space distance over the chain
joints, radians / metres), the planner's extensions and the simplifier's shortcuts alike
(:func:`path_is_free` is the same check of a polyline, used for the straight path). Joints
outside the chain (e.g. the fingers) keep their start values on the way and take the goal's at
the goal.

The motion cost of a path is its joint-space length (:func:`path_length`): the sum of the
Euclidean lengths of its segments over the chain joints, so a straight path costs the straight
distance and a detour costs what it travels.

A goal that cannot be reached gives a :class:`PathPlanningError` whose message says why: the goal
(or start) configuration itself is invalid (outside the limits, self-collision, or which bodies
enter blocked cells), or no path was found within ``timeout_s``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from nbv_prob_cnn.arm.collision import CollisionChecker, GridObstacles


class PathPlanningError(ValueError):
    """No collision-free joint path; the message says why (``reason`` is a short code:
    ``invalid_start``, ``invalid_goal`` or ``timeout``)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


#: The returned path is checked again at ``resolution_rad / VERIFY_DIVISOR``.
VERIFY_DIVISOR = 10


@dataclass(frozen=True)
class PathPlannerSettings:
    """How :class:`JointPathPlanner` plans.

    Attributes:
        timeout_s: planning time limit of RRTConnect (s); the goal is given up after it.
        simplify_s: time limit of the shortcutting (s; checked between shortcuts, one motion
            check each).
        resolution_rad: motion validation: the largest joint-space distance (Euclidean over the
            chain joints) between two checked samples of a motion.
        range_rad: RRTConnect's longest extension step (0: OMPL's default, a fifth of the space's
            extent, about 2.8 rad for the Panda). The planner looks at the clock between
            extensions, each checked every ``resolution_rad``: a short step keeps the time limit
            (with OMPL's default and a 3DT grid a 1 s limit ran 2.4-5 s).
        seed: OMPL's random seed (None: OMPL's own). OMPL has one seed per process, taken before
            its first random number: only the first planner's seed in a process counts.
        max_attempts: paths planned per view selection at most
            (:class:`~nbv_prob_cnn.arm.feasibility.ArmFeasibility`; each may take ``timeout_s``).
    """

    timeout_s: float = 1.0
    simplify_s: float = 0.3
    resolution_rad: float = 0.05
    range_rad: float = 0.5
    seed: int | None = None
    max_attempts: int = 3

    def __post_init__(self) -> None:
        for name in ("timeout_s", "simplify_s", "resolution_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a positive finite value, got {value}")
        if not (math.isfinite(self.range_rad) and self.range_rad >= 0):
            raise ValueError(f"range_rad: expected >= 0 (0: OMPL's default), got {self.range_rad}")
        if self.max_attempts < 1:
            raise ValueError(f"max_attempts: expected >= 1, got {self.max_attempts}")


@dataclass
class JointPath:
    """A joint path: ``waypoints (k, nq)`` full configurations (first the start, last the goal),
    joined by straight segments; ``planned`` False for the straight path itself. ``seconds``:
    the whole call; ``stages``: its seconds by stage (``endpoints``: start/goal checks, ``solve``:
    RRTConnect, ``simplify``);
    ``states_before_simplify``: RRTConnect's path length in states."""

    waypoints: np.ndarray
    length: float
    planned: bool
    seconds: float = 0.0
    states_before_simplify: int = 0
    stages: dict[str, float] = field(default_factory=dict)


def path_length(waypoints: np.ndarray, chain: np.ndarray) -> float:
    """Joint-space length of a polyline: the sum of its segments' Euclidean lengths over the
    joints ``chain`` (indices into the configuration)."""
    waypoints = np.asarray(waypoints, dtype=np.float64)
    if waypoints.shape[0] < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(waypoints[:, chain], axis=0), axis=1).sum())


def dense_samples(waypoints: np.ndarray, chain: np.ndarray, resolution: float) -> np.ndarray:
    """Configurations along the polyline ``waypoints`` at most ``resolution`` apart (Euclidean over
    ``chain``), every waypoint included."""
    waypoints = np.asarray(waypoints, dtype=np.float64)
    samples = [waypoints[:1]]
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        count = max(1, math.ceil(float(np.linalg.norm((b - a)[chain])) / resolution))
        t = np.linspace(0.0, 1.0, count + 1)[1:, None]
        samples.append(a + t * (b - a))
    return np.vstack(samples)


def path_is_free(checker: CollisionChecker, waypoints: np.ndarray, obstacles: GridObstacles, resolution: float) -> bool:
    """Every sample of :func:`dense_samples` within the limits and free of self- and grid collision."""
    robot = checker.robot
    for q in dense_samples(waypoints, robot.chain, resolution):
        if not robot.within_limits(q) or not checker.is_free(q, obstacles):
            return False
    return True


_OMPL_SEEDED = False
#: Simplification ends after this many steps in a row that changed nothing.
_IDLE_STEPS = 12


def _simplify(simplifier, path, seconds: float) -> None:
    """Shorten ``path`` by OMPL's random shortcuts (``reduceVertices``: a shortcut between two
    vertices; ``partialShortcutPath``: between points on two segments), one motion check per step,
    until ``seconds`` have passed or several steps in a row changed nothing. (OMPL's
    ``simplifySolution(t)`` runs whole rounds of shortcuts before it looks at the clock: with a
    slow validity check it ran 47 s for a 0.2 s budget.)"""
    deadline, idle, step = time.perf_counter() + seconds, 0, 0
    while time.perf_counter() < deadline and idle < _IDLE_STEPS and path.getStateCount() > 2:
        changed = simplifier.reduceVertices(path, 1, 1) if step % 2 == 0 else simplifier.partialShortcutPath(path, 1, 1)
        idle = 0 if changed else idle + 1
        step += 1


def _seed_once(ou, seed: int | None) -> None:
    """Seed OMPL's random numbers; OMPL's seed is one per process and only takes before the
    first random number, so only the first seed given in a process counts."""
    global _OMPL_SEEDED
    if seed is not None and not _OMPL_SEEDED:
        ou.RNG.setSeed(int(seed))
        _OMPL_SEEDED = True


class JointPathPlanner:
    """Plans collision-free joint paths for one robot (OMPL RRTConnect + path simplifier).

    Args:
        checker: the collision check of the robot's configurations.
        settings: time limits, motion-validation resolution, seed.
    """

    def __init__(self, checker: CollisionChecker, settings: PathPlannerSettings | None = None) -> None:
        self.checker = checker
        self.robot = checker.robot
        self.settings = settings if settings is not None else PathPlannerSettings()
        self.chain = np.asarray(self.robot.chain, dtype=np.int64)
        self.lower = self.robot.lower[self.chain]
        self.upper = self.robot.upper[self.chain]

    def why_invalid(self, q: np.ndarray, obstacles: GridObstacles) -> str:
        """Why ``q`` is not a valid configuration ("" when it is)."""
        robot = self.robot
        if not robot.within_limits(q):
            outside = [
                robot.joint_names[i] for i in np.flatnonzero((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))
            ]
            return f"outside the joint limits of {outside}"
        if self.checker.self_collision(q):
            return "in self-collision"
        bodies = self.checker.grid_collisions(q, obstacles)
        if bodies:
            return f"bodies {bodies} enter occupied or unknown cells"
        return ""

    def connect(self, q_start: np.ndarray, q_goal: np.ndarray, obstacles: GridObstacles) -> JointPath:
        """The straight path when it is free at the resolution and ``VERIFY_DIVISOR`` times finer, else
        :meth:`plan`.

        Raises:
            PathPlanningError: no path (see :meth:`plan`).
        """
        start = time.perf_counter()
        q_start, q_goal = self.robot.check_q(q_start, "q_start"), self.robot.check_q(q_goal, "q_goal")
        straight = np.stack([q_start, q_goal])
        resolution = self.settings.resolution_rad
        if path_is_free(self.checker, straight, obstacles, resolution) and path_is_free(
            self.checker, straight, obstacles, resolution / VERIFY_DIVISOR
        ):  # checked again finely, as a planned path is
            return JointPath(straight, path_length(straight, self.chain), False, time.perf_counter() - start)
        return self.plan(q_start, q_goal, obstacles)

    def plan(self, q_start: np.ndarray, q_goal: np.ndarray, obstacles: GridObstacles) -> JointPath:
        """A collision-free path ``q_start → q_goal`` by RRTConnect within ``timeout_s``, simplified.

        Raises:
            PathPlanningError: the start or the goal is invalid (why, in the message), or no path
                was found in time.
        """
        import ompl.base as ob
        import ompl.geometric as og
        import ompl.util as ou

        begin = time.perf_counter()
        q_start, q_goal = self.robot.check_q(q_start, "q_start"), self.robot.check_q(q_goal, "q_goal")
        for name, q, reason in (("start", q_start, "invalid_start"), ("goal", q_goal, "invalid_goal")):
            problem = self.why_invalid(q, obstacles)
            if problem:
                raise PathPlanningError(reason, f"path planning: the {name} configuration is {problem}")
        settings = self.settings
        ou.setLogLevel(ou.LOG_WARN)
        _seed_once(ou, settings.seed)
        n = self.chain.size
        space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        for j in range(n):
            bounds.setLow(j, float(self.lower[j]))
            bounds.setHigh(j, float(self.upper[j]))
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)
        template = q_start.copy()
        checker, chain = self.checker, self.chain

        def valid(state) -> bool:
            q = template.copy()
            q[chain] = [state[j] for j in range(n)]
            return bool(space.satisfiesBounds(state)) and checker.is_free(q, obstacles)

        setup.setStateValidityChecker(valid)
        info = setup.getSpaceInformation()
        info.setStateValidityCheckingResolution(settings.resolution_rad / space.getMaximumExtent())
        planner = og.RRTConnect(info)
        if settings.range_rad > 0:
            planner.setRange(settings.range_rad)
        setup.setPlanner(planner)
        start, goal = space.allocState(), space.allocState()
        for j in range(n):
            start[j], goal[j] = float(q_start[chain[j]]), float(q_goal[chain[j]])
        setup.setStartAndGoalStates(start, goal)
        try:
            stages = {"endpoints": time.perf_counter() - begin}
            mark = time.perf_counter()
            status = setup.solve(float(settings.timeout_s))
            stages["solve"] = time.perf_counter() - mark
            if not setup.haveExactSolutionPath():
                raise PathPlanningError(
                    "timeout",
                    f"path planning: no collision-free joint path found within {settings.timeout_s:g} s "
                    f"(RRTConnect: {status.asString()})",
                )
            states_before = setup.getSolutionPath().getStateCount()
            mark = time.perf_counter()
            path = setup.getSolutionPath()
            raw_points = np.array([[path.getState(i)[j] for j in range(n)] for i in range(path.getStateCount())])
            _simplify(setup.getPathSimplifier(), path, settings.simplify_s)
            stages["simplify"] = time.perf_counter() - mark
            chain_points = np.array([[path.getState(i)[j] for j in range(n)] for i in range(path.getStateCount())])
        finally:
            setup.clear()
            del setup, planner, info
        # OMPL checks motions every resolution_rad: a link can cross a thin obstacle between two
        # samples. The returned path is checked again VERIFY_DIVISOR times finer (the simplified
        # one, else RRTConnect's own), and refused when neither is free at that resolution.
        mark = time.perf_counter()
        fine = settings.resolution_rad / VERIFY_DIVISOR
        waypoints = None
        for points in (chain_points, raw_points):
            candidate = np.repeat(template[None], points.shape[0], axis=0)
            candidate[:, chain] = points
            candidate[0], candidate[-1] = q_start, q_goal
            if path_is_free(checker, candidate, obstacles, fine):
                waypoints = candidate
                break
        stages["verify"] = time.perf_counter() - mark
        if waypoints is None:
            raise PathPlanningError(
                "not_free_between_samples",
                f"path planning: the planned path collides between its motion-validation samples "
                f"({settings.resolution_rad:g} rad apart; checked every {fine:g} rad): lower resolution_rad",
            )
        seconds = time.perf_counter() - begin
        return JointPath(waypoints, path_length(waypoints, chain), True, seconds, int(states_before), stages)


__all__ = [
    "JointPath",
    "JointPathPlanner",
    "PathPlannerSettings",
    "PathPlanningError",
    "dense_samples",
    "path_is_free",
    "path_length",
]
