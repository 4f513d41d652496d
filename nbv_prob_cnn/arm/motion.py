"""Joint-space motion of a simulated arm: straight segments through waypoints at limited joint speed.

Each segment moves every joint linearly in time from one waypoint to the next; its duration is
the longest ``|Δq_i| / v_i`` over the joints (so no joint exceeds its velocity limit ``v_i``), or the
waypoint's requested minimum duration when that is longer (``time_from_start`` of a
``JointTrajectory``). A new goal replaces the remaining waypoints and starts from where the arm
is at that moment.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class JointMotion:
    """Where a velocity-limited arm is at each time.

    Args:
        q0: initial configuration ``(nq,)``.
        velocity_limits: ``(nq,)`` positive joint speeds (rad/s or m/s).
        now: time (s) of ``q0``.

    Raises:
        ValueError: shapes differ, non-finite values or non-positive limits.
    """

    def __init__(self, q0: np.ndarray, velocity_limits: np.ndarray, now: float = 0.0) -> None:
        q0 = np.asarray(q0, dtype=np.float64).reshape(-1)
        limits = np.asarray(velocity_limits, dtype=np.float64).reshape(-1)
        if q0.shape != limits.shape:
            raise ValueError(f"velocity_limits: expected {q0.size} values, got {limits.size}")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(limits)) and np.all(limits > 0)):
            raise ValueError("motion: configuration and velocity limits must be finite, limits positive")
        self.velocity_limits = limits
        self._times = np.array([float(now)])  # arrival time of each waypoint
        self._points = q0[None].copy()

    def segment_duration(self, start: np.ndarray, goal: np.ndarray, minimum: float = 0.0) -> float:
        """Seconds of the straight segment ``start → goal`` at the velocity limits (at least ``minimum``)."""
        return max(float(minimum), float(np.max(np.abs(goal - start) / self.velocity_limits)))

    def position(self, now: float) -> np.ndarray:
        """Configuration at time ``now``."""
        times, points = self._times, self._points
        if now <= times[0]:
            return points[0].copy()
        if now >= times[-1]:
            return points[-1].copy()
        k = int(np.searchsorted(times, now, side="right"))  # times[k-1] <= now < times[k]
        fraction = (now - times[k - 1]) / (times[k] - times[k - 1])
        return points[k - 1] + fraction * (points[k] - points[k - 1])

    def velocity(self, now: float) -> np.ndarray:
        """Joint velocities at time ``now`` (0 when still)."""
        times, points = self._times, self._points
        if now < times[0] or now >= times[-1]:
            return np.zeros_like(points[0])
        k = int(np.searchsorted(times, now, side="right"))
        return (points[k] - points[k - 1]) / (times[k] - times[k - 1])

    def arrival_time(self) -> float:
        return float(self._times[-1])

    def moving(self, now: float) -> bool:
        return now < self._times[-1]

    def goal(self) -> np.ndarray:
        return self._points[-1].copy()

    def move_through(
        self, waypoints: Sequence[np.ndarray], now: float, min_durations: Sequence[float] | None = None
    ) -> float:
        """Replace the motion: from the current position at ``now`` through ``waypoints``.

        Args:
            waypoints: full configurations.
            min_durations: per waypoint, the least seconds of its segment (default 0).

        Returns:
            The arrival time at the last waypoint.

        Raises:
            ValueError: empty list, wrong sizes or non-finite values.
        """
        if len(waypoints) == 0:
            raise ValueError("trajectory: expected at least one waypoint")
        minimum = [0.0] * len(waypoints) if min_durations is None else [float(m) for m in min_durations]
        if len(minimum) != len(waypoints):
            raise ValueError("trajectory: one minimum duration per waypoint")
        start = self.position(now)
        times, points = [float(now)], [start]
        for waypoint, least in zip(waypoints, minimum, strict=True):
            q = np.asarray(waypoint, dtype=np.float64).reshape(-1)
            if q.shape != start.shape or not np.all(np.isfinite(q)):
                raise ValueError(f"trajectory: expected {start.size} finite joint positions per waypoint")
            duration = self.segment_duration(points[-1], q, least)
            if duration <= 0.0:
                continue
            times.append(times[-1] + duration)
            points.append(q)
        self._times, self._points = np.array(times), np.array(points)
        return self.arrival_time()
