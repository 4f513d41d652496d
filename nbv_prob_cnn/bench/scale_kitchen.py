"""The kitchen rows of ``nbv bench --suite scale`` (docs/performance.md#scale): a real room at the CNN's
cell, planned on whole and within an arm's reach.

The shared 7-Scenes recording (``../shared/data/rgbd/7scenes_redkitchen``, 200 frames) is fused in
this process as ``nbv integrate --voxel 0.0116 --bounds auto --depth-max 4`` does (sparse fusion, the
world turned z-up by minus the gravity direction; 568 × 294 × 178 cells at 1.16 cm), then one
``cnn_prob`` step runs in a fresh child, as in the grid rows:

* ``local`` over the whole room (every empty cell within the rays' reach of unknown space);
* ``local``, ``window`` (and ``window_bf16`` where the CPU has bfloat16 convolutions) with a workspace: a
  cube of :data:`KITCHEN_WORKSPACE_M` (an arm's reach) centred on the recording's first camera position,
  where a robot holding the camera would stand.

Today's path (the CNN over the whole room) is left out: it took 53 s and 10.2 GB on the recording's
bounding box before issue #35, and is measured on the tabletop grids.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbv_prob_cnn.bench.fusion import SHARED_RECORDING

#: Where the recording is (the rows are skipped with that reason when it is absent).
KITCHEN = SHARED_RECORDING
#: Cell of the kitchen grid (the shipped 3DT CNN's) [m].
KITCHEN_VOXEL_M = 0.0116
#: Returns beyond this are not fused [m] (the Kinect's useful range).
KITCHEN_DEPTH_MAX_M = 4.0
#: Width of the workspace cube around the first camera position [m].
KITCHEN_WORKSPACE_M = 1.5


@dataclass
class KitchenStep:
    """One measured kitchen step: the grid's label and cells, the path, the workspace width (0: the whole
    room) and :func:`~nbv_prob_cnn.bench.scale.measure`'s result."""

    grid: str
    cells: int
    path: str
    workspace_m: float
    result: dict


def kitchen_state(
    folder: str | Path = KITCHEN, voxel_m: float = KITCHEN_VOXEL_M, frames: int = 200
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The recording's first ``frames`` fused into an open grid: ``(grid, origin of cell 0 [m], first
    camera position [m])``, world z up.

    Raises:
        RecordingError: a missing or malformed recording (names the file).
    """
    from nbv_prob_cnn.bench.fusion import recording_frames
    from nbv_prob_cnn.perception import TsdfIntegrator

    integrator = TsdfIntegrator(np.zeros(3), None, voxel_m, fusion="sparse")
    first: np.ndarray | None = None
    for depth, intrinsics, pose in recording_frames(str(folder), frames):
        integrator.integrate(depth, intrinsics, pose, depth_max=KITCHEN_DEPTH_MAX_M)
        first = pose[:3, 3].copy() if first is None else first
    if first is None:
        raise ValueError(f"{folder}: no frame fused")
    origin, _ = integrator.grid_box()
    return integrator.ternary(), np.asarray(origin, dtype=np.float64), first


def camera_box(
    position_m: np.ndarray, origin_m: np.ndarray, voxel_m: float, width_m: float, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Cells ``[lo, hi)`` of a cube ``width_m`` wide centred on ``position_m``, clipped to the grid.

    Raises:
        ValueError: the cube misses the grid.
    """
    side = int(round(width_m / voxel_m))
    centre = np.floor((np.asarray(position_m) - np.asarray(origin_m)) / voxel_m).astype(int)
    lo = np.maximum(centre - side // 2, 0)
    hi = np.minimum(centre - side // 2 + side, np.asarray(shape))
    if np.any(hi <= lo):
        raise ValueError(f"workspace: a {width_m} m cube at {list(position_m)} misses the grid of {shape} cells")
    return lo, hi


def kitchen_steps(
    measure: Callable[..., dict], folder: str | Path = KITCHEN, workspace_paths: tuple[str, ...] = ("local", "window")
) -> Iterator[KitchenStep]:
    """The kitchen's steps, each yielded as soon as it is measured: ``measure(path, state, box)`` times a
    step in a child (:func:`~nbv_prob_cnn.bench.scale.measure`); the whole room on the local path, the
    workspace on ``workspace_paths``."""
    state, origin, first = kitchen_state(folder)
    label = "kitchen " + "×".join(str(s) for s in state.shape)
    box = camera_box(first, origin, KITCHEN_VOXEL_M, KITCHEN_WORKSPACE_M, state.shape)
    yield KitchenStep(label, int(state.size), "local", 0.0, measure("local", state))
    for path in workspace_paths:
        yield KitchenStep(label, int(state.size), path, KITCHEN_WORKSPACE_M, measure(path, state, box))


def kitchen_targets(rows: list) -> str:
    """Issue #35's kitchen targets on the kitchen rows (``ScaleRow``): the workspace step ≤ 1.5 s and ≤ 2 GB,
    per path; any whole-room step ≤ 4 GB."""
    work = [r for r in rows if r.grid.startswith("kitchen") and r.workspace_m]
    whole = [r for r in rows if r.grid.startswith("kitchen") and not r.workspace_m]

    def verdict(oks: list[bool]) -> str:
        return "not measured" if not oks else "met" if all(oks) else "NOT met"

    def per_path(ok) -> str:
        paths = list(dict.fromkeys(r.path for r in work))
        return ", ".join(f"{p} {verdict([ok(r) for r in work if r.path == p])}" for p in paths) or "not measured"

    return (
        f"targets (kitchen): {KITCHEN_WORKSPACE_M} m workspace ≤ 1.5 s: {per_path(lambda r: r.seconds <= 1.5)}; "
        f"{KITCHEN_WORKSPACE_M} m workspace ≤ 2 GB: {per_path(lambda r: r.peak_rss_mb <= 2048.0)}; "
        f"whole room ≤ 4 GB: {verdict([r.peak_rss_mb <= 4096.0 for r in whole])}"
    )
