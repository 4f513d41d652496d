"""Ranked views and view masks as flat arrays, the compact form ``/nbv/rank_views`` carries
(``RankViews.srv``: ``allowed_views`` in the request, the ``ranked_*`` arrays in the reply).

A list of 20 000 :class:`~nbv_prob_cnn.planners.ViewChoice` as one ``ViewScore`` message each
costs seconds to build and parse in Python; as five arrays it is a few copies. The arrays name
each view by its origin's flat cell index (x fastest, the order grids travel in) and its
orientation index, so the receiver needs no pose → view inversion. No ROS here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.planners.base import PlanningContext, ViewChoice, ViewMask
from nbv_prob_cnn.planners.requests import flat_cells


@dataclass
class RankedArrays:
    """Ranked views, best first: ``cells (N,)`` flat origin indices, ``orientations (N,)``,
    ``positions (N, 3)`` metres (cell centres), ``quaternions (N, 4)`` xyzw, ``gains (N,)``."""

    cells: np.ndarray
    orientations: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    gains: np.ndarray


def ranked_to_arrays(ranked: list[ViewChoice], context: PlanningContext, geometry: GridGeometry) -> RankedArrays:
    """The arrays of ranked views (see :class:`RankedArrays`)."""
    count = len(ranked)
    cells = np.array([c.cell for c in ranked], dtype=np.int64).reshape(count, geometry.dims)
    views = np.array([c.view_index for c in ranked], dtype=np.int64)
    table = np.array([context.view_quaternion(i) for i in range(len(context.orientations))], dtype=np.float64)
    return RankedArrays(
        flat_cells(cells, tuple(geometry.shape)),
        views,
        geometry.cell_centre(cells).reshape(count, 3) if count else np.zeros((0, 3)),
        table[views].reshape(count, 4),
        np.array([c.gain for c in ranked], dtype=np.float32),
    )


def ranked_from_arrays(
    cells: np.ndarray, orientations: np.ndarray, gains: np.ndarray, shape: tuple[int, ...], n_views: int
) -> list[ViewChoice]:
    """:class:`ViewChoice` objects of the array form (the inverse of :func:`ranked_to_arrays`).

    Raises:
        ValueError: arrays of different lengths, a cell outside the grid or an orientation index
            outside ``[0, n_views)``.
    """
    cells = np.asarray(cells, dtype=np.int64).ravel()
    orientations = np.asarray(orientations, dtype=np.int64).ravel()
    gains = np.asarray(gains, dtype=np.float64).ravel()
    if not (cells.size == orientations.size == gains.size):
        raise ValueError(
            f"ranked views: {cells.size} cells, {orientations.size} orientations and {gains.size} gains: lengths differ"
        )
    if cells.size and (cells.min() < 0 or cells.max() >= int(np.prod(shape))):
        raise ValueError(f"ranked views: cell indices must lie in [0, {int(np.prod(shape))})")
    if orientations.size and (orientations.min() < 0 or orientations.max() >= n_views):
        raise ValueError(f"ranked views: orientation indices must lie in [0, {n_views})")
    grid_cells = np.stack(np.unravel_index(cells, shape, order="F"), axis=1)
    return [
        ViewChoice(cell, int(view), float(gain))
        for cell, view, gain in zip(grid_cells, orientations.tolist(), gains.tolist(), strict=True)
    ]


def view_mask_to_bytes(allowed_cells: np.ndarray, mask: np.ndarray) -> bytes:
    """``allowed_views`` of a request: one byte (1 = allowed) per orientation of each allowed
    origin, origin-major, ``mask`` being the ``(N, V)`` bool mask of those origins."""
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2 or mask.shape[0] != np.asarray(allowed_cells).reshape(-1).size:
        raise ValueError(f"view mask: expected ({np.asarray(allowed_cells).size}, V), got {mask.shape}")
    return mask.astype(np.uint8).tobytes()


def view_mask_from_bytes(allowed_flat: np.ndarray, data: bytes, shape: tuple[int, ...], n_views: int) -> ViewMask:
    """The view mask (``(N, dims)`` origins → ``(N, V)`` bool) of a request's ``allowed_origins``
    and ``allowed_views``; an origin that is not among the allowed ones gets no orientation.

    Raises:
        ValueError: ``data`` is not ``len(allowed_flat) × n_views`` bytes.
    """
    allowed = np.asarray(allowed_flat, dtype=np.int64).ravel()
    table = np.frombuffer(data, dtype=np.uint8)
    if table.size != allowed.size * n_views:
        raise ValueError(
            f"allowed_views: expected {allowed.size} allowed origins × {n_views} orientations = "
            f"{allowed.size * n_views} bytes, got {table.size}"
        )
    order = np.argsort(allowed, kind="stable")
    keys, rows = allowed[order], table.reshape(allowed.size, n_views)[order] != 0

    def mask(origins: np.ndarray) -> np.ndarray:
        flat = flat_cells(origins, shape)
        at = np.minimum(np.searchsorted(keys, flat), max(keys.size - 1, 0))
        found = (keys.size > 0) & (keys[at] == flat) if keys.size else np.zeros(flat.size, dtype=bool)
        out = np.zeros((flat.size, n_views), dtype=bool)
        out[found] = rows[at[found]]
        return out

    return mask
