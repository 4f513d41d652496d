"""Reconstruction metrics that view planners are compared by, beside the unknown fraction:

* **surface coverage**: the share of the ground-truth surface that was observed. The surface is
  the set of ground-truth occupied cells with at least one ground-truth empty face neighbour (the
  cells a camera in free space can see); a surface cell counts as observed when a cell the
  camera has seen occupied lies within one cell of it (its 3×3(×3) neighbourhood), so a surface
  seen one cell off, as a noisy depth camera sees it, still counts;
* **Chamfer distance** between two point sets (a reconstruction's mesh vertices or occupied cell
  centres against points of the ground-truth meshes): the mean nearest-neighbour distance from
  each set to the other, averaged over both directions (metres when the points are);
* **views to a coverage level**: the first view after which the coverage reaches it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED


def surface_cells(ground_truth: np.ndarray) -> np.ndarray:
    """Boolean mask of the ground-truth surface: occupied cells (``ground_truth == 1``) with an
    empty (``0``) face neighbour inside the grid. 2D or 3D."""
    truth = np.asarray(ground_truth)
    if truth.ndim not in (2, 3):
        raise ValueError(f"ground_truth: expected a 2D or 3D grid, got shape {truth.shape}")
    empty = truth == EMPTY
    faces = ndimage.generate_binary_structure(truth.ndim, 1)
    return (truth == OCCUPIED) & ndimage.binary_dilation(empty, structure=faces)


class SurfaceCoverage:
    """The surface coverage of states of one ground truth: its surface (:func:`surface_cells`) is
    found once, each call measures one state."""

    def __init__(self, ground_truth: np.ndarray) -> None:
        self.shape = np.shape(ground_truth)
        self.surface = surface_cells(ground_truth)
        self.surface_count = int(self.surface.sum())

    def __call__(self, state: np.ndarray) -> float:
        """Share of the surface cells within one cell (the full 3×3(×3) neighbourhood) of a cell
        seen occupied in ``state`` (ternary: -1 unknown, 0 empty, 1 occupied). 1.0 when the
        truth has no surface."""
        state = np.asarray(state)
        if state.shape != self.shape:
            raise ValueError(f"state: shape {state.shape} differs from ground_truth's {self.shape}")
        if self.surface_count == 0:
            return 1.0
        seen = state == OCCUPIED
        near_seen = ndimage.binary_dilation(seen, structure=np.ones((3,) * state.ndim, dtype=bool))
        return float(np.count_nonzero(self.surface & near_seen) / self.surface_count)


def surface_coverage(state: np.ndarray, ground_truth: np.ndarray) -> float:
    """:class:`SurfaceCoverage` of ``ground_truth`` measured once, on ``state``."""
    return SurfaceCoverage(ground_truth)(state)


def chamfer_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance of two point sets ``(N, d)`` and ``(M, d)``: the mean distance
    from each point of ``a`` to its nearest point of ``b`` and that of ``b`` to ``a``, averaged
    (``(mean_a + mean_b) / 2``), in the points' unit."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    for name, points in (("a", a), ("b", b)):
        if points.ndim != 2 or points.shape[0] == 0:
            raise ValueError(f"{name}: expected a non-empty (N, d) array of points, got shape {points.shape}")
        if not np.isfinite(points).all():
            raise ValueError(f"{name}: points must be finite")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"a, b: points of {a.shape[1]} and {b.shape[1]} coordinates")
    a_to_b = cKDTree(b).query(a)[0]
    b_to_a = cKDTree(a).query(b)[0]
    return float((a_to_b.mean() + b_to_a.mean()) / 2.0)


def views_to_coverage(coverage: Sequence[float], levels: Sequence[float] = (0.8, 0.9, 0.95)) -> dict[float, int | None]:
    """For each level, the number of views after which ``coverage`` (one value per view, in view
    order) first reaches it; None where it never does."""
    values = np.asarray(coverage, dtype=np.float64)
    out: dict[float, int | None] = {}
    for level in levels:
        reached = np.nonzero(values >= level)[0]
        out[float(level)] = int(reached[0]) + 1 if reached.size else None
    return out
