"""Reading a saved ternary grid (``nbv integrate``, the integrator's ``/integrator/save``, the
main job's ``grid.npz``) with its placement, and telling it apart from a world file.

Two kinds of ``.npz`` files travel around this project:

* a **grid**: what a camera has seen, keys ``grid`` (int8: -1 unknown, 0 empty, 1 occupied),
  ``origin`` (corner of cell 0, metres) and ``resolution`` (cell edge, metres); written by
  :func:`~nbv_prob_cnn.perception.tsdf.save_grid` and the ROS clients;
* a **world**: a generated ground truth (keys ``ground_truth``, ``origin``, ``meta``), written by
  ``nbv world``; it is what ``nbv explore`` simulates a camera in.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from nbv_prob_cnn.basics.file_kind import check_kind, sniff
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import check_state

SavedFileKind = Literal["grid", "world", "other"]

#: What a user is told a grid file holds.
GRID_KEYS = "grid (int8 -1/0/1), origin (3 floats, m), resolution (m)"


def saved_file_kind(path: str | Path) -> SavedFileKind:
    """``"grid"``, ``"world"`` or ``"other"`` (any other file, never unpickled;
    :func:`~nbv_prob_cnn.basics.file_kind.sniff`).

    Raises:
        FileNotFoundError: no such file.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    kind = sniff(path).kind
    return "grid" if kind == "grid" else "world" if kind == "world" else "other"


@dataclass
class SavedGrid:
    """A ternary grid and where it lies: ``state`` ``int8 [x, y(, z)]``, ``geometry`` (origin,
    resolution, shape) and the file it came from."""

    state: np.ndarray
    geometry: GridGeometry
    path: Path


def read_saved_grid(path: str | Path, option: str = "--grid") -> SavedGrid:
    """Read a grid file (see the module docstring); ``option`` names the argument in errors.

    Raises:
        FileNotFoundError: no such file.
        ValueError: a world file (says what to do instead), another kind of file (says which, and the
            command that takes it), or bad contents.
    """
    path = Path(path)
    kind = saved_file_kind(path)  # FileNotFoundError first
    if kind == "world":
        raise ValueError(
            f"{option} {path} is a world file (ground truth from `nbv world`), not a grid a camera has seen. "
            f"Simulate a camera in it with `nbv explore --scene {path} ...`; a grid file holds {GRID_KEYS} "
            "(`nbv integrate --bag BAG --out grid.npz`, the integrator's save service, the main job's grid.npz)."
        )
    if kind == "other":
        check_kind(path, option, ("grid",), f"a grid file (.npz with keys {GRID_KEYS})")
    with np.load(path) as data:
        state = check_state(np.asarray(data["grid"]), name=f"{path}: grid")
        origin = np.asarray(data["origin"], dtype=np.float64).reshape(-1)
        resolution = float(np.asarray(data["resolution"]))
    if origin.size not in (2, 3):
        raise ValueError(f"{path}: origin must hold 2 or 3 coordinates (m), got {origin.tolist()}")
    padded = np.zeros(3)
    padded[: origin.size] = origin
    geometry = GridGeometry((float(padded[0]), float(padded[1]), float(padded[2])), resolution, tuple(state.shape))
    return SavedGrid(state, geometry, path)
