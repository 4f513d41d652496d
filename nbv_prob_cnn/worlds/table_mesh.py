"""The noisy table of a tabletop world as a triangle mesh that matches its voxel grid (for the
simulated depth camera). It takes the world's arrays, not the world, so that the world module uses
it and neither imports the other's module."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import trimesh


def table_surface_mesh(
    truth: np.ndarray, resolution_m: float, origin_m: Sequence[float] | np.ndarray, table: Mapping[str, float]
) -> trimesh.Trimesh:
    """The noisy table of the ground-truth grid ``truth`` (cells of ``resolution_m``, lowest corner
    at ``origin_m``; ``table`` with ``height_m`` and ``thickness_m``) as a mesh that matches the
    voxel grid: each (x, y) column's top face at its own height (one cell lower or higher where
    the grid's noise says so), vertical walls where neighbouring columns differ, and a slab below
    the lowest top."""
    res = float(resolution_m)
    top = round(table["height_m"] / res)
    bottom = top - round(table["thickness_m"] / res)
    heights = np.full(truth.shape[:2], top, dtype=np.int64)
    heights[truth[:, :, top - 1] == 0] = top - 1
    heights[truth[:, :, top] == 1] = top + 1  # raised noise (or an object resting there)
    origin = np.asarray(origin_m, dtype=np.float64)
    grid_shape: tuple[int, ...] = np.shape(heights)
    nx, ny = grid_shape[0], grid_shape[1]
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    vertices: list[np.ndarray] = []
    faces: list[np.ndarray] = []

    def add_quads(corners: np.ndarray) -> None:  # corners: (n, 4, 3) in cells, counter-clockwise
        base = sum(len(v) for v in vertices)
        n = corners.shape[0]
        vertices.append(corners.reshape(-1, 3))
        idx = base + 4 * np.arange(n)[:, None]
        faces.append(np.concatenate([idx + [0, 1, 2], idx + [0, 2, 3]]))

    h = heights.astype(np.float64)
    add_quads(
        np.stack(
            [
                np.stack([ii, jj, h], -1),
                np.stack([ii + 1, jj, h], -1),
                np.stack([ii + 1, jj + 1, h], -1),
                np.stack([ii, jj + 1, h], -1),
            ],
            axis=2,
        ).reshape(-1, 4, 3)
    )
    for axis in (0, 1):  # walls between neighbouring columns of different heights
        a = heights[:-1, :] if axis == 0 else heights[:, :-1]
        b = heights[1:, :] if axis == 0 else heights[:, 1:]
        i, j = np.nonzero(a != b)
        lo, hi = np.minimum(a, b)[i, j].astype(float), np.maximum(a, b)[i, j].astype(float)
        if axis == 0:
            x = i + 1.0
            quad = [
                np.stack([x, j, lo], -1),
                np.stack([x, j + 1.0, lo], -1),
                np.stack([x, j + 1.0, hi], -1),
                np.stack([x, j, hi], -1),
            ]
        else:
            y = j + 1.0
            quad = [
                np.stack([i, y, lo], -1),
                np.stack([i + 1.0, y, lo], -1),
                np.stack([i + 1.0, y, hi], -1),
                np.stack([i, y, hi], -1),
            ]
        if i.size:
            add_quads(np.stack(quad, axis=1))
    surface = trimesh.Trimesh(np.concatenate(vertices) * res + origin, np.concatenate(faces), process=False)
    slab = trimesh.creation.box(extents=(nx * res, ny * res, (heights.min() - bottom) * res))
    slab.apply_translation(origin + [nx * res / 2, ny * res / 2, (bottom + heights.min()) * res / 2])
    merged: trimesh.Trimesh = trimesh.util.concatenate([surface, slab])  # type: ignore[assignment]
    return merged
