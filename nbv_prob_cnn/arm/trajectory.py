"""Joint trajectories as a ``joint_trajectory_controller`` takes them (no ROS here).

* :func:`time_parameterise` times a straight joint-space path (the planner's move from the
  current configuration to a view's IK solution) within per-joint velocity, acceleration and jerk
  limits: Ruckig's time-optimal jerk-limited profile of the path parameter (every joint on the
  same straight line, starting and ending at rest), sampled every ``dt``.
* :func:`check_trajectory` refuses what a controller refuses: unknown, duplicate or missing
  joints, times that do not increase, positions outside the limits, speeds over the limits.
* :func:`tolerance_violation` compares the actual state with the desired one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

#: ``control_msgs/FollowJointTrajectory`` result codes (the action's constants).
SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5


class TrajectoryError(ValueError):
    """A trajectory a controller refuses, with the ``FollowJointTrajectory`` error code."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass
class TimedPath:
    """A time-parameterised joint path.

    Attributes:
        times: ``(k,)`` seconds from the start, increasing, ``times[0] == 0``.
        positions, velocities, accelerations: ``(k, n)``.
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.times[-1])


def time_parameterise(
    start: np.ndarray,
    goal: np.ndarray,
    max_velocity: np.ndarray,
    max_acceleration: np.ndarray,
    max_jerk: np.ndarray,
    dt: float = 0.05,
) -> TimedPath:
    """The straight joint path ``start → goal``, from rest to rest, as fast as the limits allow,
    sampled every ``dt`` seconds plus the end.

    The path is ``q(s) = start + s (goal − start)`` with ``s`` from 0 to 1; Ruckig times ``s`` with
    the tightest of the joints' limits divided by their distance to go (``v_s = min_i v_i / |Δq_i|``,
    likewise acceleration and jerk), so every joint stays within its limits and on the straight
    line the planner checked for collisions.

    Raises:
        ValueError: shapes differ, non-finite values, non-positive limits or ``dt``.
    """
    from ruckig import InputParameter, Result, Ruckig, Trajectory

    start, goal = np.asarray(start, dtype=np.float64).ravel(), np.asarray(goal, dtype=np.float64).ravel()
    limits = [np.broadcast_to(np.asarray(v, dtype=np.float64), start.shape) for v in (max_velocity, max_acceleration,
                                                                                       max_jerk)]  # fmt: skip
    if goal.shape != start.shape or not (np.all(np.isfinite(start)) and np.all(np.isfinite(goal))):
        raise ValueError(f"time parameterisation: start and goal need {start.size} finite positions each")
    if not all(np.all(np.isfinite(v) & (v > 0)) for v in limits) or not dt > 0:
        raise ValueError("time parameterisation: velocity, acceleration and jerk limits and dt must be positive")
    n = start.size
    delta = goal - start
    moving = np.abs(delta) > 1e-12
    if not np.any(moving):
        zero = np.zeros((1, n))
        return TimedPath(np.zeros(1), goal[None].copy(), zero, zero.copy())
    path_limits = [float(np.min(v[moving] / np.abs(delta[moving]))) for v in limits]
    inp = InputParameter(1)
    inp.current_position, inp.target_position = [0.0], [1.0]
    inp.current_velocity = inp.current_acceleration = [0.0]
    inp.target_velocity = inp.target_acceleration = [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = ([v] for v in path_limits)
    trajectory = Trajectory(1)
    result = Ruckig(1).calculate(inp, trajectory)
    if result not in (Result.Working, Result.Finished):
        raise ValueError(f"time parameterisation: Ruckig failed ({result})")
    duration = float(trajectory.duration)
    times = np.append(np.arange(0.0, duration, dt), duration)
    if times.size > 1 and times[-1] - times[-2] < 1e-6:
        times = np.delete(times, -2)
    samples = np.array([[value[0] for value in trajectory.at_time(float(t))] for t in times])  # (k, 3): s, ṡ, s̈
    positions = start + samples[:, :1] * delta
    positions[-1] = goal  # exactly the goal the planner checked
    return TimedPath(times, positions, samples[:, 1:2] * delta, samples[:, 2:3] * delta)


def time_parameterise_path(
    waypoints: np.ndarray,
    max_velocity: np.ndarray,
    max_acceleration: np.ndarray,
    max_jerk: np.ndarray,
    dt: float = 0.05,
) -> TimedPath:
    """The polyline through ``waypoints (k, n)`` (first the start, last the goal), each segment
    timed by :func:`time_parameterise` (rest to rest, within the velocity, acceleration and jerk
    limits) and the segments run one after another; every waypoint is a sample.

    Raises:
        ValueError: fewer than one waypoint, wrong shapes, non-finite values, bad limits or ``dt``.
    """
    points = np.asarray(waypoints, dtype=np.float64)
    if points.ndim != 2 or points.shape[0] < 1:
        raise ValueError(f"time parameterisation: expected waypoints of shape (k >= 1, n), got {points.shape}")
    if points.shape[0] == 1:
        return time_parameterise(points[0], points[0], max_velocity, max_acceleration, max_jerk, dt)
    times: list[np.ndarray] = [np.zeros(1)]
    positions: list[np.ndarray] = [points[:1]]
    velocities: list[np.ndarray] = []
    accelerations: list[np.ndarray] = []
    for a, b in zip(points[:-1], points[1:], strict=True):
        segment = time_parameterise(a, b, max_velocity, max_acceleration, max_jerk, dt)
        if not velocities:
            velocities.append(segment.velocities[:1])
            accelerations.append(segment.accelerations[:1])
        if segment.times.size == 1:  # a repeated waypoint
            continue
        times.append(times[-1][-1] + segment.times[1:])
        positions.append(segment.positions[1:])
        velocities.append(segment.velocities[1:])
        accelerations.append(segment.accelerations[1:])
    return TimedPath(np.concatenate(times), np.vstack(positions), np.vstack(velocities), np.vstack(accelerations))


def check_trajectory(
    joint_names: Sequence[str],
    controller_joints: Sequence[str],
    times: Sequence[float],
    positions: Sequence[Sequence[float]],
    lower: Mapping[str, float],
    upper: Mapping[str, float],
    max_velocity: Mapping[str, float],
    start: Mapping[str, float],
    tolerance: float = 1e-6,
) -> None:
    """Refuse a trajectory a ``joint_trajectory_controller`` would not run.

    Args:
        joint_names: the trajectory's joints; must be exactly ``controller_joints`` (any order).
        times: ``time_from_start`` of each point (s).
        positions: per point, one position per joint name.
        lower, upper, max_velocity: limits by joint name.
        start: the joints' positions now (the first segment starts there).

    Raises:
        TrajectoryError: ``INVALID_JOINTS`` (unknown, duplicate or missing names) or
            ``INVALID_GOAL`` (no points, wrong sizes, non-finite values, times not increasing,
            positions outside the limits, a segment faster than the velocity limits).
    """
    names = [str(n) for n in joint_names]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    unknown = sorted(set(names) - set(controller_joints))
    missing = [n for n in controller_joints if n not in names]
    if duplicates or unknown or missing:
        raise TrajectoryError(
            INVALID_JOINTS,
            f"joints do not match the controller's {list(controller_joints)}: unknown {unknown}, missing {missing}, "
            f"duplicate {duplicates}",
        )
    if len(positions) == 0 or len(times) != len(positions):
        raise TrajectoryError(INVALID_GOAL, f"{len(positions)} points with {len(times)} times (need at least one)")
    q = np.asarray(positions, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != len(names):
        raise TrajectoryError(INVALID_GOAL, f"every point needs {len(names)} positions")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
        raise TrajectoryError(INVALID_GOAL, "non-finite positions or times")
    if t[0] < 0 or np.any(np.diff(t) <= 0):
        raise TrajectoryError(INVALID_GOAL, "time_from_start must be >= 0 and strictly increasing")
    lo = np.array([lower[n] for n in names])
    hi = np.array([upper[n] for n in names])
    outside = np.any((q < lo - tolerance) | (q > hi + tolerance), axis=0)
    if np.any(outside):
        bad = [n for n, o in zip(names, outside, strict=True) if o]
        raise TrajectoryError(INVALID_GOAL, f"positions outside the joint limits for {bad}")
    q0 = np.array([start[n] for n in names])
    steps = np.diff(np.vstack([q0, q]), axis=0)
    durations = np.diff(np.r_[0.0, t])
    vmax = np.array([max_velocity[n] for n in names])
    speed = np.abs(steps) / np.maximum(durations, 1e-12)[:, None]
    fast = speed > vmax * (1.0 + 1e-3) + tolerance
    if np.any(fast):
        point, joint = np.argwhere(fast)[0]
        raise TrajectoryError(
            INVALID_GOAL,
            f"point {int(point)}: joint {names[joint]!r} would move at {speed[point, joint]:.3f}, over its velocity "
            f"limit {vmax[joint]:.3f}",
        )


def tolerance_violation(
    names: Sequence[str], actual: np.ndarray, desired: np.ndarray, tolerances: Mapping[str, float]
) -> str:
    """The first joint whose ``|actual − desired|`` exceeds its tolerance (> 0; ≤ 0 = unchecked),
    described, or "" when none does."""
    for name, a, d in zip(names, np.asarray(actual), np.asarray(desired), strict=True):
        limit = tolerances.get(name, 0.0)
        if limit > 0 and math.fabs(a - d) > limit:
            return f"joint {name!r} is {math.fabs(a - d):.4f} from its setpoint (tolerance {limit:g})"
    return ""


__all__ = [
    "GOAL_TOLERANCE_VIOLATED",
    "INVALID_GOAL",
    "INVALID_JOINTS",
    "OLD_HEADER_TIMESTAMP",
    "PATH_TOLERANCE_VIOLATED",
    "SUCCESSFUL",
    "TimedPath",
    "TrajectoryError",
    "check_trajectory",
    "time_parameterise",
    "time_parameterise_path",
    "tolerance_violation",
]
