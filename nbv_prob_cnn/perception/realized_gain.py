"""What a recorded frame actually revealed: the cells it observes when fused alone, and among them
those still unknown in a grid fused earlier (the *realized gain* that ``nbv gain-study`` ranks the
predicted gains against, docs/evaluation.md#does-the-gain-predict-what-a-real-camera-sees).

:class:`Fusion` holds the TSDF settings; the same settings fuse the grid and the single frames, on
the same box (:func:`recording_box`: every cell the recording observes, and the cameras' cells), so a
cell means the same in both.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import OCCUPIED, UNKNOWN
from nbv_prob_cnn.perception.bags import Frame
from nbv_prob_cnn.perception.tsdf import DEFAULT_EMPTY_MARGIN_VOXELS, DEFAULT_TRUNC_VOXELS, TsdfIntegrator


@dataclass(frozen=True)
class Fusion:
    """TSDF fusion settings (those of ``nbv integrate`` and the integrator node by default).

    Raises:
        ValueError: a non-positive cell or depth limit (the integrator checks the rest).
    """

    voxel_m: float
    depth_max_m: float = 3.0
    trunc_voxels: float = DEFAULT_TRUNC_VOXELS
    empty_margin_voxels: float = DEFAULT_EMPTY_MARGIN_VOXELS

    def __post_init__(self) -> None:
        if not (np.isfinite(self.voxel_m) and self.voxel_m > 0):
            raise ValueError(f"voxel: expected a positive cell edge in metres, got {self.voxel_m}")
        if not (np.isfinite(self.depth_max_m) and self.depth_max_m > 0):
            raise ValueError(f"depth_max: expected a positive depth in metres, got {self.depth_max_m}")

    def integrator(self, geometry: GridGeometry | None = None) -> TsdfIntegrator:
        """A sparse integrator on ``geometry``'s box, or an open one (``None``: the grid spans what is seen)."""
        origin = np.zeros(3) if geometry is None else np.asarray(geometry.origin, dtype=np.float64)
        shape = None if geometry is None else (int(geometry.shape[0]), int(geometry.shape[1]), int(geometry.shape[2]))
        return TsdfIntegrator(origin_m=origin, shape_cells=shape, voxel_size_m=self.voxel_m,
                              trunc_voxels=self.trunc_voxels, empty_margin_voxels=self.empty_margin_voxels)  # fmt: skip

    def fuse(self, integrator: TsdfIntegrator, frame: Frame) -> None:
        """Fuse one frame with these settings."""
        integrator.integrate(frame.depth_m, frame.intrinsics, frame.pose_4x4, depth_max=self.depth_max_m)


def recording_box(frames: Iterable[Frame], fusion: Fusion) -> GridGeometry:
    """The box of a recording: the smallest one, on the cell lattice anchored at the world origin,
    that holds every cell its frames observe (fused with ``fusion``: the returns up to the depth
    limit, the free space in front of them, the truncation band behind) and every camera's cell.

    Raises:
        ValueError: no frame, or no frame observes anything.
    """
    integrator = fusion.integrator(None)
    cameras = []
    for frame in frames:
        fusion.fuse(integrator, frame)
        cameras.append(frame.pose_4x4[:3, 3])
    if not cameras:
        raise ValueError("frames: the recording holds no frame")
    origin, shape = integrator.grid_box()
    lo = np.rint(origin / fusion.voxel_m).astype(np.int64)
    hi = lo + np.asarray(shape) - 1
    if integrator.ternary().max() == UNKNOWN:
        raise ValueError("frames: no frame observes a cell (no depth return within the depth limit)")
    camera_cells = np.floor(np.asarray(cameras) / fusion.voxel_m).astype(np.int64)
    lo, hi = np.minimum(lo, camera_cells.min(axis=0)), np.maximum(hi, camera_cells.max(axis=0))
    x, y, z = (float(v) for v in lo * fusion.voxel_m)
    return GridGeometry((x, y, z), fusion.voxel_m, tuple(int(v) for v in hi - lo + 1))


class SingleFrameObserver:
    """The cells one frame observes when fused alone on ``geometry`` with ``fusion``."""

    def __init__(self, geometry: GridGeometry, fusion: Fusion) -> None:
        self._integrator = fusion.integrator(geometry)
        self._fusion = fusion

    def observed(self, frame: Frame) -> np.ndarray:
        """``bool`` grid: the cells that ``frame`` alone labels (not unknown)."""
        return self.labels(frame) != UNKNOWN

    def labels(self, frame: Frame) -> np.ndarray:
        """The ternary grid of ``frame`` fused alone (``int8``: unknown, empty, occupied)."""
        self._integrator.reset()
        self._fusion.fuse(self._integrator, frame)
        return self._integrator.ternary()


def realized_surface(anchor_state: np.ndarray, labels: np.ndarray) -> int:
    """How many cells unknown in ``anchor_state`` the frame saw occupied (``labels`` from
    :meth:`SingleFrameObserver.labels`, same shape): the new surface it gave.

    Raises:
        ValueError: the two grids differ in shape.
    """
    if anchor_state.shape != labels.shape:
        raise ValueError(f"labels: shape {labels.shape} differs from the grid's {anchor_state.shape}")
    return int(np.count_nonzero((anchor_state == UNKNOWN) & (labels == OCCUPIED)))


def realized_gain(anchor_state: np.ndarray, observed: np.ndarray) -> int:
    """How many cells unknown in ``anchor_state`` the frame observed (``observed`` from
    :meth:`SingleFrameObserver.observed`, same shape).

    Raises:
        ValueError: the two grids differ in shape.
    """
    if anchor_state.shape != observed.shape:
        raise ValueError(f"observed: shape {observed.shape} differs from the grid's {anchor_state.shape}")
    return int(np.count_nonzero((anchor_state == UNKNOWN) & observed))
