"""Grid geometry: conversions between world metres and cell indices (no ROS).

A grid is axis-aligned in its frame; cell ``i`` spans ``origin + [i, i+1) * resolution`` and
its centre is at ``origin + (i + 0.5) * resolution``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.basics.region import Region


@dataclass(frozen=True)
class GridGeometry:
    """Placement of a grid in its frame: ``origin`` (metres, corner of cell 0), cell edge
    ``resolution`` (metres) and ``shape`` (cells)."""

    origin: tuple[float, float, float]
    resolution: float
    shape: tuple[int, ...]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution: expected a positive cell size in metres, got {self.resolution}")
        if np.shape(self.origin) != (3,) or not np.all(np.isfinite(self.origin)):
            raise ValueError(
                f"origin: expected 3 finite coordinates in metres (z too for a 2D grid), got {self.origin}"
            )
        if (
            len(self.shape) not in (2, 3)
            or not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in self.shape)
            or min(self.shape) < 1
        ):
            raise ValueError(f"shape: expected 2 (x, y) or 3 (x, y, z) positive integer sizes, got {self.shape}")

    @property
    def dims(self) -> int:
        return len(self.shape)

    def window(self, corner: tuple[int, ...], shape: tuple[int, ...]) -> GridGeometry:
        """The geometry of the part of this grid of ``shape`` cells starting at cell ``corner``."""
        origin = np.asarray(self.origin, dtype=np.float64).copy()
        origin[: len(corner)] += np.asarray(corner, dtype=np.float64) * self.resolution
        return GridGeometry((float(origin[0]), float(origin[1]), float(origin[2])), self.resolution, tuple(shape))

    def box_region(self, box_min: np.ndarray, box_max: np.ndarray) -> Region | None:
        """A cell box ``(lo, hi)`` (``hi`` exclusive) holding every cell whose centre lies in the axis-aligned
        box (metres; :meth:`cells_in_box`'s cells), one cell wider on each side against rounding and
        clipped to the grid; None when no cell of the grid can be in it.

        Raises:
            ValueError: non-finite bounds or ``box_min > box_max`` on some axis.
        """
        self.cells_in_box(np.zeros((0, self.dims), dtype=np.int64), box_min, box_max)  # validates the bounds
        # centre i in [min, max] <=> to_index(min) <= i <= to_index(max)
        lo = np.ceil(self.to_index(np.asarray(box_min, dtype=np.float64)[:3])).astype(np.int64) - 1
        hi = np.floor(self.to_index(np.asarray(box_max, dtype=np.float64)[:3])).astype(np.int64) + 2
        lo, hi = np.maximum(lo, 0), np.minimum(hi, np.asarray(self.shape))
        if np.any(hi <= lo):
            return None
        return tuple(int(v) for v in lo), tuple(int(v) for v in hi)

    def cell_centre(self, cell: np.ndarray) -> np.ndarray:
        """World position (3 components, z = origin z in 2D) of cell centres ``(..., dims)``."""
        cell = np.asarray(cell, dtype=np.float64)
        xyz = np.broadcast_to(np.asarray(self.origin, dtype=np.float64), cell.shape[:-1] + (3,)).copy()
        xyz[..., : self.dims] += (cell + 0.5) * self.resolution
        return xyz

    def to_index(self, xyz: np.ndarray) -> np.ndarray:
        """Continuous index coordinates (centre of cell ``i`` at ``i``) of positions ``(..., 3)``."""
        xyz = np.asarray(xyz, dtype=np.float64)
        return (xyz[..., : self.dims] - np.asarray(self.origin)[: self.dims]) / self.resolution - 0.5

    def containing_cell(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell index containing each position, and whether it lies inside the grid."""
        cell = np.floor(self.to_index(xyz) + 0.5).astype(np.int64)
        inside = np.all((cell >= 0) & (cell < np.array(self.shape)), axis=-1)
        return cell, inside

    def cells_in_box(self, cells: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
        """Boolean mask of the cells whose centre lies in the axis-aligned box (metres).

        Raises:
            ValueError: non-finite bounds or ``box_min > box_max`` on some axis.
        """
        lo, hi = np.asarray(box_min, dtype=np.float64), np.asarray(box_max, dtype=np.float64)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(lo[: self.dims] > hi[: self.dims]):
            raise ValueError(f"workspace: expected finite bounds with min <= max, got {lo.tolist()} .. {hi.tolist()}")
        centres = self.cell_centre(cells)[..., : self.dims]
        return np.all((centres >= lo[: self.dims]) & (centres <= hi[: self.dims]), axis=-1)
