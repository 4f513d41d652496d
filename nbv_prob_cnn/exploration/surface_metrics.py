"""Reconstruction metrics that view planners are compared by, beside the unknown fraction:

* **surface coverage**: the share of the ground-truth surface that was observed. The surface is
  the set of ground-truth occupied cells with at least one ground-truth empty face neighbour (the
  cells a camera in free space can see); given where the run starts, only those whose empty
  neighbour lies in the start's free space (:func:`free_space_of`: the empty cells face-connected
  to it, all a camera that starts there can ever see or stand in; on 3DT not the underside of the
  table, facing the closed gap below it, 47 % of all surface cells); a surface cell counts as
  observed when a cell the camera has seen occupied lies within one cell of it (its 3×3(×3)
  neighbourhood), so a surface seen one cell off, as a noisy depth camera sees it, still counts;
* **Chamfer distance** between two point sets (a reconstruction's mesh vertices or occupied cell
  centres against points of the ground-truth meshes): the mean nearest-neighbour distance from
  each set to the other, averaged over both directions (metres when the points are);
* **points on a mesh** (:func:`sample_surface_points`), spread uniformly over its area, where the
  Chamfer distance of two meshes is measured (:mod:`~nbv_prob_cnn.exploration.mesh_chamfer`);
* **views to a coverage level**: the first view after which the coverage reaches it.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED


def surface_cells(ground_truth: np.ndarray, start: Sequence[int] | np.ndarray | None = None) -> np.ndarray:
    """Boolean mask of the ground-truth surface: occupied cells (``ground_truth == 1``) with an
    empty (``0``) face neighbour inside the grid; with ``start`` (an empty cell), with one in
    :func:`free_space_of` ``start``. 2D or 3D."""
    truth = np.asarray(ground_truth)
    if truth.ndim not in (2, 3):
        raise ValueError(f"ground_truth: expected a 2D or 3D grid, got shape {truth.shape}")
    empty = truth == EMPTY if start is None else free_space_of(truth, start)
    faces = ndimage.generate_binary_structure(truth.ndim, 1)
    return (truth == OCCUPIED) & ndimage.binary_dilation(empty, structure=faces)


def free_space_of(ground_truth: np.ndarray, start: Sequence[int] | np.ndarray) -> np.ndarray:
    """Boolean mask of the ground-truth empty cells face-connected to cell ``start`` (itself
    empty): the free space a camera that starts there can see (a simulated ray steps from cell to
    cell through their faces) and move in (it views from cells it has seen empty).

    Raises:
        ValueError: ``start`` outside the grid or not empty.
    """
    truth = np.asarray(ground_truth)
    cell = tuple(int(v) for v in np.asarray(start).reshape(-1))
    if len(cell) != truth.ndim or any(not 0 <= c < n for c, n in zip(cell, truth.shape, strict=True)):
        raise ValueError(f"start: {list(cell)} is no cell of the grid of shape {truth.shape}")
    if truth[cell] != EMPTY:
        raise ValueError(f"start: cell {list(cell)} is not empty in the ground truth")
    labels, _ = ndimage.label(truth == EMPTY, structure=ndimage.generate_binary_structure(truth.ndim, 1))
    return labels == labels[cell]


class SurfaceCoverage:
    """The surface coverage of states of one ground truth: its surface (:func:`surface_cells`, of
    the free space of ``start`` when given) and the flat indices of each surface cell's
    3×3(×3) neighbourhood are found once, each call measures one state (a gather of those
    neighbours: 1.3 ms on a 3DT grid, where dilating the whole grid took 100 ms; 0.3 s once per
    grid)."""

    def __init__(self, ground_truth: np.ndarray, start: Sequence[int] | np.ndarray | None = None) -> None:
        self.shape = np.shape(ground_truth)
        self.surface = surface_cells(ground_truth, start)
        self.surface_count = int(self.surface.sum())
        cells = np.argwhere(self.surface)
        offsets = np.array(list(itertools.product((-1, 0, 1), repeat=len(self.shape))))
        # a neighbour outside the grid is clipped onto one inside the same neighbourhood
        around = np.clip(cells[:, None, :] + offsets[None], 0, np.array(self.shape) - 1)
        self._neighbours = np.ravel_multi_index(tuple(np.moveaxis(around, -1, 0)), self.shape)

    @classmethod
    def seen_from(cls, ground_truth: np.ndarray, first_view: Sequence[int] | np.ndarray) -> SurfaceCoverage:
        """The coverage of a run whose first view stands in cell ``first_view``: of the surface of
        its free space (all the surface when that cell is not empty)."""
        cell = tuple(int(v) for v in np.asarray(first_view).reshape(-1))
        return cls(ground_truth, cell if np.asarray(ground_truth)[cell] == EMPTY else None)

    def __call__(self, state: np.ndarray) -> float:
        """Share of the surface cells within one cell (the full 3×3(×3) neighbourhood) of a cell
        seen occupied in ``state`` (ternary: -1 unknown, 0 empty, 1 occupied). 1.0 when the
        truth has no surface."""
        state = np.asarray(state)
        if state.shape != self.shape:
            raise ValueError(f"state: shape {state.shape} differs from ground_truth's {self.shape}")
        if self.surface_count == 0:
            return 1.0
        seen = (state == OCCUPIED).reshape(-1)
        return float(np.count_nonzero(seen[self._neighbours].any(axis=1)) / self.surface_count)


def surface_coverage(
    state: np.ndarray, ground_truth: np.ndarray, start: Sequence[int] | np.ndarray | None = None
) -> float:
    """:class:`SurfaceCoverage` of ``ground_truth`` (and ``start``) measured once, on ``state``."""
    return SurfaceCoverage(ground_truth, start)(state)


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


def triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area of each triangle ``(F,)`` of a mesh (``vertices (V, 3)``, ``triangles (F, 3)`` indices)."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64).reshape(-1, 3)]
    return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)


def sample_surface_points(
    vertices: np.ndarray, triangles: np.ndarray, count: int, rng: np.random.Generator
) -> np.ndarray:
    """``count`` points ``(count, 3)`` spread uniformly over the area of a triangle mesh
    (:func:`sample_surface`)."""
    return sample_surface(vertices, triangles, count, rng)[0]


def sample_surface(
    vertices: np.ndarray, triangles: np.ndarray, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points ``(count, 3)`` spread uniformly over the area of a triangle mesh, and the
    index of the triangle of each: a triangle drawn with probability proportional to its area,
    then a uniform point in it (barycentric ``(1 - sqrt(r1), sqrt(r1) (1 - r2), sqrt(r1) r2)``).
    Empty for a mesh without area or ``count`` 0."""
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if count < 0:
        raise ValueError(f"count: expected >= 0, got {count}")
    if triangles.size and (triangles.min() < 0 or triangles.max() >= len(vertices)):
        raise ValueError("triangles: vertex indices out of range")
    areas = triangle_areas(vertices, triangles)
    total = float(areas.sum())
    if count == 0 or not total > 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    index = rng.choice(len(areas), size=count, p=areas / total)
    chosen = vertices[triangles[index]]  # (count, 3 corners, 3)
    root, r2 = np.sqrt(rng.random(count))[:, None], rng.random(count)[:, None]
    return (1.0 - root) * chosen[:, 0] + root * (1.0 - r2) * chosen[:, 1] + root * r2 * chosen[:, 2], index


def views_to_coverage(
    coverage: Sequence[float] | np.ndarray, levels: Sequence[float] = (0.8, 0.9, 0.95)
) -> dict[float, int | None]:
    """For each level, the number of views after which ``coverage`` (one value per view, in view
    order) first reaches it; None where it never does."""
    values = np.asarray(coverage, dtype=np.float64)
    out: dict[float, int | None] = {}
    for level in levels:
        reached = np.nonzero(values >= level)[0]
        out[float(level)] = int(reached[0]) + 1 if reached.size else None
    return out
