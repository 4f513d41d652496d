"""One arm-constrained view choice, as ``nbv study arm_compare`` (:class:`~studies.arm_comparison.ArmPlanner`)
and the ROS ``nbv_planner`` (``use_arm``) both make it: :func:`~nbv_prob_cnn.arm.feasibility.plan_with_arm`
on the grid with the space the arm has swept carved free, never a view already taken, and a
near-camera fallback when no ranked view is feasible.

The caller says where the arm is (``current_q``), what it has swept (:attr:`ArmViewSelector.swept`)
and which views it took (:meth:`ArmViewSelector.moved`); the camera's own map is never changed.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from nbv_prob_cnn.arm.feasibility import ArmFeasibility, ArmView, FeasibilityReport, plan_with_arm
from nbv_prob_cnn.arm.swept import SweptVolume
from nbv_prob_cnn.basics.camera import orientations
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.planners import PlanningContext, ViewChoice


class ArmViewSelector:
    """Chooses the next view the arm takes on one grid geometry.

    Args:
        arm: feasibility check (capability map, IK, collision, motion cost).
        geometry: the grid.
        swept: with a :class:`SweptVolume`, its cells count as free (UNKNOWN → EMPTY) in the grid
            the gain planner and the collision check see; None: the camera's map only.
        fallback_radius_m: > 0: when no ranked view is feasible, rank again among the origins
            within this distance of the camera (small moves, whose links mostly stay in swept
            space) before giving up; 0: off.

    Views taken (:meth:`take`) are never ranked again: in a static scene a view repeated shows
    nothing new, while the gain model may still credit it (seen in ``nbv study arm_compare``: a view kept
    its ``prob_ig`` gain after being taken and the arm, unable to reach the better ones, took it
    again and again).
    """

    def __init__(
        self,
        arm: ArmFeasibility,
        geometry: GridGeometry,
        swept: SweptVolume | None = None,
        fallback_radius_m: float = 0.0,
    ) -> None:
        if not (np.isfinite(fallback_radius_m) and fallback_radius_m >= 0):
            raise ValueError(f"fallback_radius_m: expected a finite radius >= 0 (0 = off), got {fallback_radius_m}")
        if swept is not None and tuple(swept.free.shape) != tuple(geometry.shape):
            raise ValueError(f"swept: expected a volume of shape {tuple(geometry.shape)}, got {swept.free.shape}")
        self.arm = arm
        self.geometry = geometry
        self.swept = swept
        self.fallback_radius_m = float(fallback_radius_m)
        self.taken: set[tuple[tuple[int, ...], int]] = set()  # (cell, orientation) of the views taken
        self.n_views = len(orientations(3))  # the arm plans in 3D grids

    def take(self, choice: ViewChoice) -> None:
        """Never rank this (cell, orientation) again."""
        self.taken.add((tuple(int(c) for c in choice.cell), int(choice.view_index)))

    def moved(self, q_start: np.ndarray, view: ArmView) -> None:
        """The arm moved from ``q_start`` to ``view``: its joint path (straight, or the planned
        waypoints' segments) is swept, the view taken."""
        if self.swept is not None:
            points = [q_start, view.q] if view.waypoints is None else list(view.waypoints)
            for a, b in zip(points[:-1], points[1:], strict=True):
                self.swept.add_path(a, b)
        self.take(view.choice)

    def not_taken(self, origins: np.ndarray) -> np.ndarray:
        """``(N, V)`` view mask: False for the (cell, orientation) pairs already taken."""
        allowed = np.ones((origins.shape[0], self.n_views), dtype=bool)
        for (i, j, k), view in self.taken:
            allowed[(origins[:, 0] == i) & (origins[:, 1] == j) & (origins[:, 2] == k), view] = False
        return allowed

    def near_camera(self, current_q: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
        """Origin filter: the origins whose cell centre lies within ``fallback_radius_m`` of the
        camera at ``current_q``."""
        camera = self.arm.robot.camera_pose(current_q)[:3, 3]
        radius, geometry = self.fallback_radius_m, self.geometry

        def keep(origins: np.ndarray) -> np.ndarray:
            return origins[np.linalg.norm(geometry.cell_centre(origins) - camera, axis=1) <= radius]

        return keep

    def known(self, state: np.ndarray) -> np.ndarray:
        """The grid the planner sees: ``state`` with the swept cells carved free (a copy), or
        ``state`` itself without a swept volume."""
        return state if self.swept is None else self.swept.carve(state)

    def select(
        self, planner, state: np.ndarray, context: PlanningContext, current_q: np.ndarray, top_k: int
    ) -> FeasibilityReport:
        """The arm's next view from ``current_q`` (``report.view`` None: none feasible, even near
        the camera). When the fallback ran, the report is the pass near the camera, the first in
        its ``first_pass``: :meth:`FeasibilityReport.total` sums both (counts and times)."""
        args = (planner, self.known(state), context, self.geometry, self.arm, current_q, top_k)
        report = plan_with_arm(*args, view_mask=self.not_taken)
        if report.view is None and self.fallback_radius_m > 0:
            first = report
            report = plan_with_arm(*args, origin_filter=self.near_camera(current_q), view_mask=self.not_taken)
            report.fallback, report.first_pass = True, first
        return report
