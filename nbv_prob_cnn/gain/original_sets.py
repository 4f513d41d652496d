"""The ray and orientation sets of the authors' host code (differences 5–6 of docs/original_code.md),
for ``PlanningContext(view_set="original")``; the paper's sets are :func:`~nbv_prob_cnn.gain.ray_directions`
and :func:`~nbv_prob_cnn.basics.camera.orientations`.

* Rays: the cells of a ``16``-cube (3D: its 16³ − 14³ = 1352 boundary cells, the paper's
  ``N_rays = 16`` bearings) or of the whole ``16 × 16`` square (2D: all 256 cells, the interior
  ones too, so interior directions are cast again), each as the unit vector from the centre.
  Every ray is binned to the boundary cell its bearing points at (2D: 60 bins); a ray belongs to
  a view when its *bin's* bearing lies in the view's frustum. With the original gain's
  sum-of-hits over sum-of-totals (item 4), a bin hit by several rays weighs more.
* Orientations: 2D, the 60 bin bearings (not 60 yaws every 6°); 3D, the original's
  "standard orientation set" of 8 angles: azimuths every 45° × elevations −90°, 0°, +90°, plus
  straight up and down, × rolls 0° and 90° (52 orientations, 10 distinct optical axes).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from nbv_prob_cnn.basics.camera import in_frustum, quaternion_from_matrix

#: Cells per side of the authors' view cube.
VIEW_CUBE = 16


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)


def _centres(dims: int, n: int, boundary_only: bool) -> np.ndarray:
    """Cell centres relative to the cube centre, lexicographic in the cell index (first slowest)."""
    c = np.arange(n) + 0.5 - n / 2.0
    cells = [idx for idx in itertools.product(range(n), repeat=dims) if not boundary_only or 0 in idx or n - 1 in idx]
    return np.array([[c[i] for i in idx] for idx in cells], dtype=np.float64)


def bin_bearings(directions: np.ndarray, n: int = VIEW_CUBE) -> np.ndarray:
    """The bearing of the boundary cell each direction points at: the direction scaled to the
    cube's surface (its largest component ±1), mapped to cell ``floor((x + 1) n / 2)`` (clamped),
    as the unit vector to that cell's centre."""
    d = np.asarray(directions, dtype=np.float64)
    on_surface = d / np.abs(d).max(axis=1, keepdims=True)
    cell = np.clip(np.floor((on_surface + 1.0) * n / 2.0), 0, n - 1)
    return _unit(cell + 0.5 - n / 2.0)


def original_rays(dims: int, n: int = VIEW_CUBE) -> tuple[np.ndarray, np.ndarray]:
    """``(directions, bins)``, each ``(R, dims)`` unit vectors: the rays the original casts and
    the bearing of each ray's bin (2D: R = n², 3D: R = n³ − (n − 2)³)."""
    if dims not in (2, 3):
        raise ValueError(f"dims: expected 2 or 3, got {dims}")
    directions = _unit(_centres(dims, n, boundary_only=dims == 3))
    return directions, bin_bearings(directions, n)


def original_orientations(dims: int, n: int = VIEW_CUBE) -> np.ndarray:
    """2D: ``(4n − 4,)`` yaws of the bin bearings (boundary cells in lexicographic order); 3D:
    ``(52, 4)`` quaternions ``(x, y, z, w)`` of the standard set (optical axis = third column)."""
    if dims == 2:
        bins = _unit(_centres(2, n, boundary_only=True))
        return np.arctan2(bins[:, 1], bins[:, 0])
    if dims != 3:
        raise ValueError(f"dims: expected 2 or 3, got {dims}")

    def rot(axis: int, angle: float) -> np.ndarray:
        c, s = math.cos(angle), math.sin(angle)
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        m = np.eye(3)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    quats = []
    for roll in (0.0, math.pi / 2):  # 2 rolls about the optical axis
        for azimuth in range(8):
            for elevation in (-1, 0, 1):
                m = rot(2, azimuth * math.pi / 4) @ rot(1, elevation * math.pi / 2) @ rot(1, math.pi / 2) @ rot(2, roll)
                quats.append(quaternion_from_matrix(m))
        quats.append(quaternion_from_matrix(rot(2, roll)))  # straight up (+z)
        quats.append(quaternion_from_matrix(rot(1, math.pi) @ rot(2, roll)))  # straight down
    return np.array(quats)


def original_view_set(dims: int, hfov_deg: float, vfov_deg: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(directions, orientations, membership)`` of the original sets; ``membership`` ``(R, V)``
    float32: the ray's bin bearing lies in the view's frustum (``hfov_deg``/``vfov_deg``)."""
    directions, bins = original_rays(dims)
    views = original_orientations(dims)
    return directions, views, in_frustum(bins, views, hfov_deg, vfov_deg).astype(np.float32)
