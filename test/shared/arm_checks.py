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
    origin = np.asarray(geometry.origin)
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        count = max(1, math.ceil(np.abs(b - a).max() / DENSE_STEP))
        for t in np.linspace(0.0, 1.0, count + 1):
            q = a + t * (b - a)
            if np.any(q < robot.lower - 1e-9) or np.any(q > robot.upper + 1e-9) or checker.self_collision(q):
                return False
            cells = np.floor((checker.body_points(q) - origin) / geometry.resolution).astype(int)
            inside = np.all((cells >= 0) & (cells < np.array(geometry.shape)), axis=1)
            c = cells[inside]
            if np.any(state[c[:, 0], c[:, 1], c[:, 2]] != EMPTY):
                return False
    return True
