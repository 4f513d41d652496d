"""The kitchen rows of ``nbv bench --suite scale`` (docs/performance.md#scale): a real room at the CNN's
cell, planned on whole and within an arm's reach.

The shared 7-Scenes recording (``../shared/data/rgbd/7scenes_redkitchen``, 200 frames) is fused in
this process as ``nbv integrate --voxel 0.0116 --bounds auto --depth-max 4`` does (sparse fusion, the
world turned z-up by minus the gravity direction; 568 × 294 × 178 cells at 1.16 cm), then one
``cnn_prob`` step runs in a fresh child, as in the grid rows:

* ``local`` over the whole room (every empty cell within the rays' reach of unknown space);
* ``local`` and ``window`` with a workspace: a cube of :data:`KITCHEN_WORKSPACE_M` (an arm's reach)
  centred on the recording's first camera position, where a robot holding the camera would stand.

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


def kitchen_steps(measure: Callable[..., dict], folder: str | Path = KITCHEN) -> Iterator[KitchenStep]:
    """The kitchen's steps, each yielded as soon as it is measured: ``measure(path, state, box)`` times a
    step in a child (:func:`~nbv_prob_cnn.bench.scale.measure`)."""
    state, origin, first = kitchen_state(folder)
    label = "kitchen " + "×".join(str(s) for s in state.shape)
    box = camera_box(first, origin, KITCHEN_VOXEL_M, KITCHEN_WORKSPACE_M, state.shape)
    yield KitchenStep(label, int(state.size), "local", 0.0, measure("local", state))
    for path in ("local", "window"):
        yield KitchenStep(label, int(state.size), path, KITCHEN_WORKSPACE_M, measure(path, state, box))


def kitchen_targets(rows: list) -> str:
    """Issue #35's kitchen targets on the kitchen rows (``ScaleRow``): the workspace step local path ≤ 1.5 s and
    ≤ 2 GB; any whole-room step ≤ 4 GB."""
    work = [r for r in rows if r.grid.startswith("kitchen") and r.workspace_m and r.path == "local"]
    whole = [r for r in rows if r.grid.startswith("kitchen") and not r.workspace_m]
    checks = [(f"{KITCHEN_WORKSPACE_M} m workspace ≤ 1.5 s", [r.seconds <= 1.5 for r in work]),
              (f"{KITCHEN_WORKSPACE_M} m workspace ≤ 2 GB", [r.peak_rss_mb <= 2048.0 for r in work]),
              ("whole room ≤ 4 GB", [r.peak_rss_mb <= 4096.0 for r in whole])]  # fmt: skip
    return "targets (kitchen): " + "; ".join(
        f"{name}: {'not measured' if not oks else 'met' if all(oks) else 'NOT met'}" for name, oks in checks
    )
