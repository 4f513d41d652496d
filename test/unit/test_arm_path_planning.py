"""Joint paths that are not straight (OMPL RRTConnect + simplifier) and their timing, on hand-built
scenes: a pillar of occupied cells across the straight path of a base rotation, a goal inside the
pillar, and a goal enclosed in a shell of occupied cells.

Paths are checked by an independent dense sampler: every segment interpolated at most
``DENSE_STEP`` rad apart per joint (ten times finer than the planner's 0.05 rad motion-validation
resolution), each sample checked for joint limits, self-collision (coal, through pinocchio) and
grid collision by looking the bodies' sample points up in the ternary grid directly (not through
``GridObstacles.hits``, nor OMPL's validator)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("ompl")

from arm_checks import dense_free  # noqa: E402
from scipy import ndimage  # noqa: E402

from nbv_prob_cnn.arm.collision import CollisionChecker, GridObstacles  # noqa: E402
from nbv_prob_cnn.arm.feasibility import ArmFeasibility, FeasibilityReport  # noqa: E402
from nbv_prob_cnn.arm.path_planning import (  # noqa: E402
    JointPathPlanner,
    PathPlannerSettings,
    PathPlanningError,
    path_length,
)
from nbv_prob_cnn.arm.robot import RobotModel  # noqa: E402
from nbv_prob_cnn.arm.trajectory import time_parameterise_path  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED  # noqa: E402

RESOLUTION = 0.04  # cell edge (m) of the hand-built grids
RESOLUTION_RAD = 0.05  # the planner's motion-validation resolution
TIMEOUT = 2.0


@pytest.fixture(scope="module")
def scene():
    robot = RobotModel()
    checker = CollisionChecker(robot, spacing=0.75 * RESOLUTION)
    geometry = GridGeometry((-1.1, -0.35, -0.05), RESOLUTION, (56, 56, 36))
    q_start = robot.reference_q.copy()
    q_goal = q_start.copy()
    q_goal[0] = 1.8  # the base joint turns 1.8 rad
    halfway = q_start.copy()
    halfway[0] = 0.9
    camera = robot.camera_pose(halfway)[:3, 3]
    lo = np.floor((camera - 0.1 - geometry.origin) / RESOLUTION).astype(int)
    hi = np.floor((camera + 0.1 - geometry.origin) / RESOLUTION).astype(int)
    state = np.full(geometry.shape, EMPTY, dtype=np.int8)
    state[lo[0] : hi[0] + 1, lo[1] : hi[1] + 1, : hi[2] + 1] = OCCUPIED  # a pillar from the floor to above the camera
    return robot, checker, geometry, state, q_start, q_goal, halfway


@pytest.fixture(scope="module")
def planned(scene):
    robot, checker, geometry, state, q_start, q_goal, _ = scene
    planner = JointPathPlanner(checker, PathPlannerSettings(timeout_s=TIMEOUT, resolution_rad=RESOLUTION_RAD, seed=7))
    return planner.connect(q_start, q_goal, GridObstacles.from_state(state, geometry))


def test_straight_path_collides_and_the_planned_one_is_free(scene, planned):
    robot, checker, geometry, state, q_start, q_goal, _ = scene
    assert dense_free(robot, checker, geometry, state, np.stack([q_start, q_start]))
    assert dense_free(robot, checker, geometry, state, np.stack([q_goal, q_goal]))
    assert not dense_free(robot, checker, geometry, state, np.stack([q_start, q_goal]))  # the pillar is in the way
    assert planned.planned
    np.testing.assert_array_equal(planned.waypoints[0], q_start)
    np.testing.assert_array_equal(planned.waypoints[-1], q_goal)
    assert planned.waypoints.shape[0] >= 3  # not straight
    assert dense_free(robot, checker, geometry, state, planned.waypoints)
    # motion cost: the path's joint-space length, longer than the straight distance (1.8 rad)
    length = sum(math.dist(a[:7], b[:7]) for a, b in zip(planned.waypoints[:-1], planned.waypoints[1:], strict=True))
    assert planned.length == pytest.approx(length, rel=1e-9)
    assert length > 1.8 + 1e-3


def test_a_free_straight_path_is_kept(scene):
    robot, checker, geometry, _, q_start, q_goal, _ = scene
    empty = GridObstacles.from_state(np.full(geometry.shape, EMPTY, dtype=np.int8), geometry)
    path = JointPathPlanner(checker).connect(q_start, q_goal, empty)
    assert not path.planned and path.waypoints.shape[0] == 2
    assert path.length == pytest.approx(1.8)


def test_timed_planned_path_respects_the_limits_and_passes_every_waypoint(scene, planned):
    robot = scene[0]
    vmax = np.asarray(robot.model.velocityLimit, dtype=np.float64) * 0.5
    amax, jmax, dt = 1.5, 15.0, 0.002
    timed = time_parameterise_path(planned.waypoints, vmax, amax, jmax, dt)
    np.testing.assert_allclose(timed.positions[0], planned.waypoints[0], atol=1e-12)
    np.testing.assert_allclose(timed.positions[-1], planned.waypoints[-1], atol=1e-12)
    for waypoint in planned.waypoints:  # each waypoint is a sample, the arm at rest there
        k = int(np.argmin(np.abs(timed.positions - waypoint).max(axis=1)))
        assert np.abs(timed.positions[k] - waypoint).max() < 1e-9
        assert np.abs(timed.velocities[k]).max() < 1e-6
    steps = np.diff(timed.times)
    assert np.all(steps > 0) and steps.max() <= dt + 1e-12
    uniform = np.abs(steps - dt) < 1e-9  # finite differences over evenly spaced samples
    velocity = np.diff(timed.positions, axis=0) / steps[:, None]
    assert np.all(np.abs(velocity) <= vmax * (1 + 1e-6) + 1e-9)
    both = uniform[:-1] & uniform[1:]
    acceleration = np.diff(velocity, axis=0)[both] / dt
    assert np.abs(acceleration).max() <= amax + jmax * dt + 1e-6
    # every sample lies on the checked polyline: between two consecutive waypoints
    a, b = planned.waypoints[:-1], planned.waypoints[1:]
    for q in timed.positions[:: max(1, len(timed.positions) // 200)]:
        t = np.clip(np.einsum("kj,kj->k", q - a, b - a) / np.maximum(np.einsum("kj,kj->k", b - a, b - a), 1e-12), 0, 1)
        assert np.min(np.linalg.norm(a + t[:, None] * (b - a) - q, axis=1)) < 1e-9


def test_two_segment_path_duration_is_hand_worked():
    # 0 → 1 → 0 with v = a = 1 and a jerk so high the profile is a triangle: each segment
    # accelerates for 1 s to 1 rad/s and brakes for 1 s (2 s), stopping at the corner: 4 s
    timed = time_parameterise_path(np.array([[0.0], [1.0], [0.0]]), 1.0, 1.0, 1e5, dt=0.01)
    assert timed.duration == pytest.approx(4.0, abs=1e-3)
    assert timed.positions.max() == pytest.approx(1.0, abs=1e-12)
    assert timed.positions[-1, 0] == 0.0


def test_goal_inside_an_occupied_block_is_refused_at_once(scene):
    robot, checker, geometry, state, q_start, _, halfway = scene
    planner = JointPathPlanner(checker, PathPlannerSettings(timeout_s=TIMEOUT))
    begin = time.perf_counter()
    with pytest.raises(PathPlanningError, match="goal configuration is bodies .*panda_hand.* enter occupied") as info:
        planner.plan(q_start, halfway, GridObstacles.from_state(state, geometry))
    assert info.value.reason == "invalid_goal"
    assert time.perf_counter() - begin < 0.5


def test_enclosed_goal_gives_up_after_the_time_limit(scene):
    robot, checker, geometry, _, q_start, q_goal, _ = scene

    def filled(q):
        cells = np.zeros(geometry.shape, dtype=bool)
        c, inside = geometry.containing_cell(checker.body_points(q))
        cells[tuple(c[inside].T)] = True
        return cells

    pocket = filled(q_goal)  # the arm at the goal fits in a pocket, walled in by 2 cells on every side
    shell = ndimage.binary_dilation(pocket, iterations=2) & ~pocket & ~filled(q_start)
    obstacles = GridObstacles.from_state(np.where(shell, OCCUPIED, EMPTY).astype(np.int8), geometry)
    assert checker.is_free(q_start, obstacles) and checker.is_free(q_goal, obstacles)
    timeout = 0.5
    planner = JointPathPlanner(checker, PathPlannerSettings(timeout_s=timeout))
    begin = time.perf_counter()
    with pytest.raises(PathPlanningError, match=r"no collision-free joint path found within 0.5 s") as info:
        planner.plan(q_start, q_goal, obstacles)
    assert info.value.reason == "timeout"
    assert time.perf_counter() - begin < timeout + 1.0


def test_feasibility_takes_the_planned_path_where_the_straight_one_is_blocked(scene):
    robot, checker, geometry, state, q_start, q_goal, _ = scene
    obstacles = GridObstacles.from_state(state, geometry)
    target = robot.camera_pose(q_goal)
    straight_only = ArmFeasibility(robot, checker, path_step=0.02)
    report = FeasibilityReport(None)
    goal, failure, waypoints = straight_only._free_goal(q_goal, target, q_start, obstacles, report)
    assert goal is None and failure == "path" and waypoints is None
    settings = PathPlannerSettings(timeout_s=TIMEOUT, max_attempts=1)
    with_paths = ArmFeasibility(robot, checker, path_step=0.02, path_planner=JointPathPlanner(checker, settings))
    goal, failure, waypoints = with_paths._free_goal(q_goal, target, q_start, obstacles, report)
    assert failure == "" and np.array_equal(goal, q_goal) and report.paths_planned == 1
    assert dense_free(robot, checker, geometry, state, waypoints)
    assert report.times["path_planning"] > 0
    # the arm-check line names the path's stages and its joint length (as path_length computes it)
    assert set(report.path_stages) >= {"solve", "simplify", "verify"}
    assert report.path_length_rad == pytest.approx(path_length(waypoints, with_paths.chain.q_index))
    assert "(path: " in report.summary() and "verify" in report.summary()
    assert f"length {report.path_length_rad:.2f} rad" in report.summary()
    goal, failure, _ = with_paths._free_goal(q_goal, target, q_start, obstacles, report)  # budget spent
    assert goal is None and failure == "path" and report.paths_planned == 1


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="timeout_s"):
        PathPlannerSettings(timeout_s=0)
    with pytest.raises(ValueError, match="resolution_rad"):
        PathPlannerSettings(resolution_rad=float("nan"))
    with pytest.raises(ValueError, match="max_attempts"):
        PathPlannerSettings(max_attempts=0)


def test_the_simulated_arm_follows_the_timed_path_on_the_polyline(scene, planned):
    """arm_sim runs a FollowJointTrajectory goal through :class:`JointMotion` (linear between the
    points, at most at its velocity limits): the timed planned path arrives on time and every
    executed position lies on the checked polyline."""
    from nbv_prob_cnn.arm.motion import JointMotion

    robot = scene[0]
    limits = np.asarray(robot.model.velocityLimit, dtype=np.float64)
    timed = time_parameterise_path(planned.waypoints, 0.5 * limits, 1.5, 15.0, 0.05)
    motion = JointMotion(planned.waypoints[0], limits, now=0.0)
    arrival = motion.move_through(list(timed.positions[1:]), 0.0, list(np.diff(timed.times)))
    assert arrival == pytest.approx(timed.duration, abs=1e-9)
    a, b = planned.waypoints[:-1], planned.waypoints[1:]
    for t in np.linspace(0.0, arrival, 400):
        q = motion.position(t)
        s = np.clip(np.einsum("kj,kj->k", q - a, b - a) / np.einsum("kj,kj->k", b - a, b - a), 0.0, 1.0)
        assert np.min(np.linalg.norm(a + s[:, None] * (b - a) - q, axis=1)) < 1e-9
    np.testing.assert_allclose(motion.position(arrival), planned.waypoints[-1], atol=1e-12)


def test_a_thin_obstacle_between_the_coarse_samples_blocks_the_straight_path(scene):
    """One occupied cell that the arm's sample points cross only between the 0.1 rad samples of the
    straight path check (found by sampling the sweep at the dense sampler's step): the coarse check
    alone calls the path free; feasibility and ``connect`` check it again finely and refuse it, as
    the independent dense sampler does."""
    robot, checker, geometry, _, q_start, _, _ = scene
    q_goal = q_start.copy()
    q_goal[0] += 0.25  # three 0.1 rad steps
    origin = np.asarray(geometry.origin)

    def cells(q):
        found = np.floor((checker.body_points(q) - origin) / geometry.resolution).astype(int)
        return {tuple(c) for c in found if np.all((c >= 0) & (c < np.array(geometry.shape)))}

    coarse = set().union(*(cells(q_start + t * (q_goal - q_start)) for t in np.linspace(0, 1, 4)))
    fine = set().union(*(cells(q_start + t * (q_goal - q_start)) for t in np.linspace(0, 1, 51)))
    between = sorted(fine - coarse)
    assert between, "the sweep crosses no cell between the coarse samples"
    state = np.full(geometry.shape, EMPTY, dtype=np.int8)
    state[between[len(between) // 2]] = OCCUPIED
    obstacles = GridObstacles.from_state(state, geometry)
    assert checker.is_free(q_start, obstacles) and checker.is_free(q_goal, obstacles)
    assert checker.path_is_free(q_start, q_goal, obstacles, 0.1)  # the coarse samples miss it
    assert not dense_free(robot, checker, geometry, state, np.array([q_start, q_goal]))
    arm = ArmFeasibility(robot, checker, path_step=0.1)
    goal, failure, _ = arm._free_goal(q_goal, robot.camera_pose(q_goal), q_start, obstacles, FeasibilityReport(None))
    assert goal is None and failure == "path"
    # connect (coarse resolution 0.1 rad): not the straight path; a planned one that is free, or the
    # planner's own refusal of a plan that collides between its samples
    planner = JointPathPlanner(checker, PathPlannerSettings(timeout_s=TIMEOUT, resolution_rad=0.1, seed=3))
    try:
        path = planner.connect(q_start, q_goal, obstacles)
    except PathPlanningError as exc:
        assert "between its motion-validation samples" in str(exc)
    else:
        assert path.planned and dense_free(robot, checker, geometry, state, path.waypoints)
