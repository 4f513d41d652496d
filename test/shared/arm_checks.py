"""Independent checks of arm paths, shared by the unit and the ROS tests (``test/shared`` is on the
tests' import path)."""

from __future__ import annotations

import math

import numpy as np

from nbv_prob_cnn.basics.grid import EMPTY

DENSE_STEP = 0.005  # the independent sampler's step (rad, per joint)


def dense_free(robot, checker, geometry, state, waypoints) -> bool:
    """The independent dense check of a polyline of configurations: every configuration every
    :data:`DENSE_STEP` along it is inside the joint limits, free of self-collision, and its body
    points lie in cells known empty (or outside the grid)."""
    return not first_blocked(robot, checker, geometry, state, waypoints)


def first_blocked(robot, checker, geometry, state, waypoints) -> str:
    """What :func:`dense_free` finds first on the polyline ("" when it is free): the segment, the
    fraction along it, and the limit, the self-collision or the cells entered with their values."""
    origin = np.asarray(geometry.origin)
    for k, (a, b) in enumerate(zip(waypoints[:-1], waypoints[1:], strict=True)):
        count = max(1, math.ceil(np.abs(b - a).max() / DENSE_STEP))
        for t in np.linspace(0.0, 1.0, count + 1):
            q = a + t * (b - a)
            where = f"segment {k} of {len(waypoints) - 1} at t = {t:.4f}"
            if np.any(q < robot.lower - 1e-9) or np.any(q > robot.upper + 1e-9):
                return f"{where}: outside the joint limits"
            if checker.self_collision(q):
                return f"{where}: self-collision"
            cells = np.floor((checker.body_points(q) - origin) / geometry.resolution).astype(int)
            inside = np.all((cells >= 0) & (cells < np.array(geometry.shape)), axis=1)
            c = cells[inside]
            hit = state[c[:, 0], c[:, 1], c[:, 2]] != EMPTY
            if np.any(hit):
                entered = {tuple(int(v) for v in cell): int(state[tuple(cell)]) for cell in c[hit]}
                return f"{where}: enters cells (cell: value) {entered}"
    return ""
