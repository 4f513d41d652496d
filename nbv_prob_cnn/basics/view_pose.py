"""From a planner's answer (a grid cell and a candidate-orientation index) to a camera pose in
metres and a quaternion.

The view search works in cells and orientation indices: a view is "camera at the centre of empty
cell ``cell``, oriented as candidate orientation ``view_index``" (docs/method.md, "Candidate
views"). A robot wants a pose. This module turns the one into the other, given where the grid lies
(:class:`~nbv_prob_cnn.basics.geometry.GridGeometry`: the corner of cell 0 and the cell edge in
metres). Imports no ROS.

Conventions (the same as the ROS nodes'): the position is the centre of the cell,
``origin + (cell + 0.5) * resolution`` (2D grids: z is the origin's z); in 3D the quaternion
``(x, y, z, w)`` rotates the REP-103 optical frame (z forward, x right, y down) into the grid
frame; in 2D it is the rotation by the view's yaw about +z (the camera looks along its +x).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.basics.camera import orientations as candidate_orientations
from nbv_prob_cnn.basics.camera import yaw_quaternion
from nbv_prob_cnn.basics.geometry import GridGeometry

__all__ = ["ViewPose", "view_pose", "view_quaternion"]


@dataclass(frozen=True)
class ViewPose:
    """A candidate view as a pose.

    Attributes:
        cell: grid index of the camera's cell (2 or 3 integers).
        view_index: index into the candidate orientations.
        position_m: ``(3,)`` camera position in the grid frame, metres (the cell centre).
        quaternion_xyzw: ``(4,)`` unit quaternion ``(x, y, z, w)`` of the camera in the grid frame.
        gain: the view's gain when known (NaN otherwise).
    """

    cell: tuple[int, ...]
    view_index: int
    position_m: np.ndarray
    quaternion_xyzw: np.ndarray
    gain: float = float("nan")

    def as_row(self) -> list[float]:
        """``[x_m, y_m, z_m, qx, qy, qz, qw]``."""
        return [*map(float, self.position_m), *map(float, self.quaternion_xyzw)]


def view_quaternion(view_index: int, dims: int, orientations: np.ndarray | None = None) -> np.ndarray:
    """Quaternion ``(x, y, z, w)`` of candidate orientation ``view_index`` (2D: rotation by its yaw
    about +z).

    Args:
        view_index: index into ``orientations``.
        dims: 2 or 3.
        orientations: the candidate orientations (default: :func:`~nbv_prob_cnn.basics.camera.orientations`
            of ``dims``: 60 yaws in 2D, 52 quaternions in 3D).

    Raises:
        ValueError: ``view_index`` outside the candidate orientations, or bad ``dims``.
    """
    table = candidate_orientations(dims) if orientations is None else np.asarray(orientations, dtype=np.float64)
    if not isinstance(view_index, (int, np.integer)) or not 0 <= int(view_index) < len(table):
        raise ValueError(f"view_index: expected an integer in [0, {len(table)}), got {view_index!r}")
    orientation = table[int(view_index)]
    if dims == 2:
        return yaw_quaternion(float(orientation))
    quat = np.asarray(orientation, dtype=np.float64).reshape(4)
    return quat / np.linalg.norm(quat)


def view_pose(
    cell: np.ndarray | tuple[int, ...],
    view_index: int,
    geometry: GridGeometry,
    orientations: np.ndarray | None = None,
    gain: float = float("nan"),
) -> ViewPose:
    """The pose of the view "camera at cell ``cell``, orientation ``view_index``" in a grid placed by
    ``geometry``.

    Raises:
        ValueError: ``cell`` has the wrong length, is not integer or lies outside the grid, or
            ``view_index`` is not a candidate orientation.
    """
    index = np.asarray(cell)
    if index.shape != (geometry.dims,) or not np.issubdtype(index.dtype, np.integer):
        raise ValueError(
            f"cell: expected {geometry.dims} integer indices (geometry: shape {tuple(geometry.shape)}; "
            f"a {index.size}D grid needs a {index.size}D geometry), got {np.asarray(cell).tolist()!r}"
        )
    if np.any(index < 0) or np.any(index >= np.array(geometry.shape)):
        raise ValueError(f"cell: {index.tolist()} lies outside the grid of shape {tuple(geometry.shape)}")
    quat = view_quaternion(view_index, geometry.dims, orientations)
    position = geometry.cell_centre(index)
    return ViewPose(tuple(int(v) for v in index), int(view_index), position, quat, float(gain))
