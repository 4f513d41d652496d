"""The space the robot has swept: cells its bodies have filled are known to be free.

A static scene cannot hold an obstacle where a link has been, so every cell that held one of the
robot's collision sample points (:meth:`CollisionChecker.body_points`, the convex hull of each
collision mesh on a lattice finer than the cells) at a configuration the robot was in, or at a
sample of a joint path it moved along, is free. :meth:`SweptVolume.carve` writes that knowledge
into a copy of the camera's ternary grid (UNKNOWN → EMPTY; OCCUPIED cells stay occupied), which
the arm-constrained planner then uses for its candidate origins, its gains and the collision
check. The camera's own map (and so the unknown fraction of an exploration) is left alone.

Only sampled poses are carved (samples at most ``path_step`` rad apart, both ends included), so
the carved set is a subset of the space truly swept; what lies between two samples stays unknown.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.arm.collision import CollisionChecker
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import EMPTY, UNKNOWN, check_state


class SweptVolume:
    """Cells of ``geometry`` the robot's moving bodies have filled.

    Args:
        checker: provides the bodies' sample points at a configuration.
        geometry: the grid.
        path_step: joint-space sampling step (rad) of :meth:`add_path`.
    """

    def __init__(self, checker: CollisionChecker, geometry: GridGeometry, path_step: float = 0.02) -> None:
        if not (np.isfinite(path_step) and path_step > 0):
            raise ValueError(f"path_step: expected a positive step in rad, got {path_step}")
        self.checker = checker
        self.geometry = geometry
        self.path_step = float(path_step)
        self.free = np.zeros(tuple(geometry.shape), dtype=bool)

    @property
    def cell_count(self) -> int:
        return int(np.count_nonzero(self.free))

    def add_configuration(self, q: np.ndarray) -> None:
        """Mark the cells the bodies fill at ``q``."""
        cell, inside = self.geometry.containing_cell(self.checker.body_points(q))
        c = cell[inside]
        self.free[c[:, 0], c[:, 1], c[:, 2]] = True

    def add_path(self, q_start: np.ndarray, q_goal: np.ndarray) -> None:
        """Mark the cells filled along the straight joint path (samples ≤ ``path_step`` apart)."""
        robot = self.checker.robot
        q_start, q_goal = robot.check_q(q_start, "q_start"), robot.check_q(q_goal, "q_goal")
        count = max(1, int(np.ceil(np.abs(q_goal - q_start).max() / self.path_step)))
        for t in np.linspace(0.0, 1.0, count + 1):
            self.add_configuration(q_start + t * (q_goal - q_start))

    def carve(self, state: np.ndarray) -> np.ndarray:
        """A copy of ``state`` with the swept UNKNOWN cells set EMPTY.

        Raises:
            ValueError: invalid grid or a shape other than the geometry's.
        """
        state = check_state(state)
        if state.shape != self.free.shape:
            raise ValueError(f"state: expected a grid of shape {self.free.shape}, got {state.shape}")
        carved = state.copy()
        carved[self.free & (state == UNKNOWN)] = EMPTY
        return carved
