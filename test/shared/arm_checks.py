"""Independent checks of arm paths, shared by the unit and the ROS tests (``test/shared`` is on the
tests' import path)."""

from __future__ import annotations

import math

import numpy as np

from nbv_prob_cnn.basics.grid import EMPTY

DENSE_STEP = 0.005  # the independent sampler's step (rad, per joint)


def dense_free(robot, checker, geometry, state, waypoints, tolerance_m: float = 0.0) -> bool:
    """The independent dense check of a polyline of configurations: every configuration every
    :data:`DENSE_STEP` along it is inside the joint limits, free of self-collision, and its body
    points lie in cells known empty (or outside the grid); with ``tolerance_m``, a body point may
    enter blocked space by less than that (see :func:`first_blocked`)."""
    return not first_blocked(robot, checker, geometry, state, waypoints, tolerance_m)


def first_blocked(robot, checker, geometry, state, waypoints, tolerance_m: float = 0.0) -> str:
    """What :func:`dense_free` finds first on the polyline ("" when it is free): the segment, the
    fraction along it, and the limit, the self-collision or the cells entered with their values.

    ``tolerance_m`` (below a cell): a body point counts as blocked only when the cube of half-edge
    ``tolerance_m`` around it lies in non-empty cells (all its 8 corners do: with a half-edge below a
    cell that is the same), i.e. it entered blocked space that deep. Two samplers of the same path at
    different positions disagree on grazes shallower than a sampling step's motion (a 0.005 rad step
    moves a Panda body point up to about 1 cm): the planner, free at its own samples, can graze a
    cell between them by a fraction of a millimetre where this sampler lands."""
    origin = np.asarray(geometry.origin)
    shape = np.array(geometry.shape)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64) * tolerance_m

    def blocked_at(points):
        cells = np.floor((points - origin) / geometry.resolution).astype(int)
        inside = np.all((cells >= 0) & (cells < shape), axis=1)
        hit = np.zeros(points.shape[0], dtype=bool)
        c = cells[inside]
        hit[inside] = state[c[:, 0], c[:, 1], c[:, 2]] != EMPTY
        return hit, cells

    for k, (a, b) in enumerate(zip(waypoints[:-1], waypoints[1:], strict=True)):
        count = max(1, math.ceil(np.abs(b - a).max() / DENSE_STEP))
        for t in np.linspace(0.0, 1.0, count + 1):
            q = a + t * (b - a)
            where = f"segment {k} of {len(waypoints) - 1} at t = {t:.4f}"
            if np.any(q < robot.lower - 1e-9) or np.any(q > robot.upper + 1e-9):
                return f"{where}: outside the joint limits"
            if checker.self_collision(q):
                return f"{where}: self-collision"
            points = checker.body_points(q)
            hit, cells = blocked_at(points)
            if tolerance_m > 0 and np.any(hit):
                deep = np.ones(int(hit.sum()), dtype=bool)
                for corner in corners:
                    deep &= blocked_at(points[hit] + corner)[0]
                hit[np.flatnonzero(hit)[~deep]] = False
            if np.any(hit):
                entered = {tuple(int(v) for v in cell): int(state[tuple(cell)]) for cell in cells[hit]}
                depth = f" by at least {tolerance_m * 1000:g} mm" if tolerance_m > 0 else ""
                return f"{where}: enters cells (cell: value){depth} {entered}"
    return ""
