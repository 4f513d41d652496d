"""Ray directions and sample offsets of the omnidirectional ray casting
(docs/method.md#probabilistic-ray-casting-gain)."""

from __future__ import annotations

import itertools

import numpy as np


def ray_directions(dims: int, n_rays: int) -> np.ndarray:
    """Unit ray directions through the boundary sub-cells of a square (2D) or cube (3D).

    The square/cube is centred on the origin cell and split into ``n_rays`` sub-cells per
    side; each boundary sub-cell gives the unit vector from the centre to its centre.
    Order: lexicographic in the sub-cell index ``(i, j[, k])``, ``i`` slowest, each from the
    negative to the positive side.

    Returns:
        ``(R, dims)`` float64, ``R = n^d - (n-2)^d`` (2D n=16: 60; 3D n=4: 56; n=16: 1352).
    """
    if dims not in (2, 3):
        raise ValueError(f"dims: expected 2 or 3, got {dims}")
    if not isinstance(n_rays, (int, np.integer)) or n_rays < 2:
        raise ValueError(f"n_rays: expected an integer >= 2 sub-cells per side, got {n_rays!r}")
    centres = np.arange(n_rays) + 0.5 - n_rays / 2.0
    dirs = [
        [centres[i] for i in idx]
        for idx in itertools.product(range(n_rays), repeat=dims)
        if any(i in (0, n_rays - 1) for i in idx)
    ]
    unit = np.array(dirs, dtype=np.float64)
    return unit / np.linalg.norm(unit, axis=1, keepdims=True)


def check_directions(directions: np.ndarray, dims: int) -> np.ndarray:
    """Validate ``(R, dims)`` unit direction vectors; return them as float64."""
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != dims or d.shape[0] == 0:
        raise ValueError(f"directions: expected a non-empty (R, {dims}) array, got shape {d.shape}")
    if not np.all(np.isfinite(d)) or not np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6):
        raise ValueError("directions: expected finite unit vectors")
    return d


def sample_offsets(directions: np.ndarray, r_max: int) -> np.ndarray:
    """Integer cell offsets ``round(t * b_h)`` for ``t = 0..r_max`` (round half up).

    Since the origin ``v`` is a cell index, ``round(v + t b) = v + round(t b)``: both
    backends read the same table, so they sample exactly the same cells.

    Returns:
        ``(R, r_max + 1, dims)`` int16.
    """
    t = np.arange(r_max + 1, dtype=np.float64)
    return np.floor(t[None, :, None] * directions[:, None, :] + 0.5).astype(np.int16)


def distance_weights(r_max: int, dims: int) -> np.ndarray:
    """``t^nu`` for ``t = 0..r_max`` with ``nu = 1`` (2D) or ``2`` (3D), float64."""
    return np.arange(r_max + 1, dtype=np.float64) ** (dims - 1)
