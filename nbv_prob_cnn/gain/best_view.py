"""The answer of :func:`~nbv_prob_cnn.gain.best_origin_view`: still the 3-tuple ``(index, view,
gain)`` it always was, and it also knows the origin's cell and turns into a pose."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.view_pose import ViewPose, view_pose


class _IndexViewGain(NamedTuple):
    origin_index: int
    view: int
    gain: float


class BestOriginView(_IndexViewGain):
    """``(origin_index, view, gain)``: position of the best origin in the ``origins`` that were
    searched (-1 when there were none), candidate-orientation index and gain. Unpacks and compares
    as a 3-tuple; ``cell`` is the origin's grid index (None when ``origin_index`` is -1).

    Example::

        best = best_origin_view(state, prob, dirs, 24, member)
        i, view, gain = best                    # as before
        pose = best.pose(GridGeometry((0.0, 0.0, 0.0), 0.02, state.shape))
        pose.position_m, pose.quaternion_xyzw   # metres, (x, y, z, w)
    """

    cell: tuple[int, ...] | None

    def __new__(cls, index: int, view: int, gain: float, cell: np.ndarray | None = None) -> BestOriginView:
        self = super().__new__(cls, int(index), int(view), float(gain))
        self.cell = None if cell is None or index < 0 else tuple(int(v) for v in np.asarray(cell).reshape(-1))
        return self

    def pose(self, geometry: GridGeometry, orientations: np.ndarray | None = None) -> ViewPose:
        """The view as a pose in metres with a quaternion (see :func:`~nbv_prob_cnn.basics.view_pose.view_pose`).

        Raises:
            ValueError: there was no origin (``origin_index`` -1), or the cell/view does not fit ``geometry``.
        """
        if self.cell is None:
            raise ValueError("best view: there was no candidate origin, so there is no pose")
        return view_pose(self.cell, self.view, geometry, orientations, gain=self.gain)
