"""The grid the OpenCL ray caster marches (``raycast.cl``): one float code per cell (unknown: its
occupancy probability; -1 occupied; empty: minus one minus a lower bound of the distance to the
nearest non-empty cell), padded with occupied cells, and linear indices into it."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_cdt

#: Padding code of the grid border where the original ``ig`` must tell it from occupied cells
#: (outside the grid is empty to the original code; above ``ORIGINAL_BORDER`` of the kernel).
ORIGINAL_BORDER_CODE = -1.5

#: Cell codes read by the kernel.
CODE_EMPTY = -1.0
CODE_OCCUPIED = -2.0

#: Largest empty-space jump encoded in the grid (cells).
MAX_SKIP = 1 << 20


def march_normals(normals: np.ndarray, padded_shape: tuple[int, int, int]) -> np.ndarray:
    """The normals of :func:`~nbv_prob_cnn.gain.sampling.occupancy_normals` laid out as three planes
    of the marched grid (:func:`march_grid`): ``(3, *padded_shape)`` float32, the padding cells
    with the border's normal (:func:`~nbv_prob_cnn.gain.sampling.border_normal`), 2D with a zero z."""
    dims = normals.shape[0]
    sizes = padded_shape[:dims]
    # per axis, -1 / +1 on the padding's low / high side, 0 inside: separable, so by broadcasting
    side = [np.where(np.arange(n) == 0, 1.0, 0.0) - np.where(np.arange(n) == n - 1, 1.0, 0.0) for n in sizes]
    faces = [side[a].reshape([-1 if b == a else 1 for b in range(dims)]) for a in range(dims)]
    norm = np.sqrt(sum(f * f for f in faces))
    norm = np.where(norm > 0, norm, 1.0)
    out = np.zeros((3, *padded_shape), dtype=np.float32)
    inner = tuple(slice(1, -1) for _ in range(dims))
    for axis in range(dims):
        plane = np.broadcast_to(faces[axis] / norm, sizes).astype(np.float32)
        plane[inner] = normals[axis]
        out[axis] = plane.reshape(padded_shape)
    return out


def encode_grid(state: np.ndarray, prob: np.ndarray | None) -> np.ndarray:
    """One float per cell: the probability of unknown cells (0 without ``prob``), -1 empty, -2 occupied."""
    code = np.full(state.shape, np.float32(CODE_EMPTY), dtype=np.float32)
    np.copyto(code, np.float32(CODE_OCCUPIED), where=state == 1)
    np.copyto(code, np.float32(0.0) if prob is None else prob, where=state == -1, casting="unsafe")
    return code


def empty_distance(empty: np.ndarray) -> np.ndarray:
    """Per cell of the bool grid ``empty`` (2D or 3D), a lower bound of the Chebyshev distance to the
    nearest non-empty cell (cells beyond the grid count as non-empty), at most 2 cells below it, >= 1
    on empty cells; 0 elsewhere. int32.

    Measured on a grid of 2 cells per axis (a coarse cell is empty when all its cells are): a cell in
    a coarse cell at coarse distance ``D >= 1`` is at least ``2 D - 1`` cells from every non-empty cell
    and at most ``2 D + 1``; one in a coarse cell holding a non-empty cell, within 1 of it. 8 times
    fewer cells than the exact transform, which cost more than the rest of a search's host work."""
    dims = empty.ndim
    even = [n + n % 2 for n in empty.shape]
    nonempty = np.ones(even, dtype=bool)
    nonempty[tuple(slice(0, n) for n in empty.shape)] = ~empty
    coarse = nonempty.reshape([v for n in even for v in (n // 2, 2)]).any(axis=tuple(range(1, 2 * dims, 2)))
    inside = tuple(slice(1, -1) for _ in range(dims))  # a non-empty coarse border: beyond the grid
    coarse_distance = distance_transform_cdt(np.pad(~coarse, 1), metric="chessboard")[inside].astype(np.int32)
    bound = np.maximum(2 * coarse_distance - 1, 1)
    wide = bound.reshape([v for n in coarse.shape for v in (n, 1)])
    fine = np.broadcast_to(wide, [v for n in coarse.shape for v in (n, 2)]).reshape(even)
    return np.where(empty, fine[tuple(slice(0, n) for n in empty.shape)], np.int32(0)).astype(np.int32)


def march_grid(code: np.ndarray, border: float = -1.0) -> np.ndarray:
    """The grid the kernels march: ``code`` (from :func:`encode_grid`) as a 3D C-ordered array
    with one occupied cell of padding on each side of every axis the rays move along (2D grids
    get a trailing axis of size 1, not padded). Occupied cells (and the padding) become -1;
    known-empty cells become ``-1 - d`` with ``d`` a lower bound of the Chebyshev distance to the
    nearest non-empty cell (:func:`empty_distance`, capped at :data:`MAX_SKIP`): the first samples
    of every ray from there are empty (see :func:`group_first_samples`). ``border``: the padding's
    code (-1, occupied; :data:`ORIGINAL_BORDER_CODE` for the original ``ig``)."""
    code3 = code if code.ndim == 3 else code[:, :, None]
    shape = tuple(n + 2 for n in code3.shape[:2]) + (code3.shape[2] + 2 if code.ndim == 3 else 1,)
    if int(np.prod(shape)) >= 2**31:
        raise ValueError(f"grid of shape {code.shape} too large for 32-bit cell indices")
    inner = (slice(1, -1), slice(1, -1), slice(1, -1) if code.ndim == 3 else slice(None))
    march = np.full(shape, np.float32(CODE_OCCUPIED), dtype=np.float32)
    march[inner] = code3
    empty = march == np.float32(CODE_EMPTY)
    occupied = march == np.float32(CODE_OCCUPIED)
    distance = empty_distance(empty if code.ndim == 3 else empty[:, :, 0]).reshape(shape)
    np.subtract(np.float32(-1.0), np.minimum(distance, MAX_SKIP), out=march, where=empty, casting="unsafe")
    march[occupied] = np.float32(-1.0)
    if border != -1.0:
        march[0], march[-1], march[:, 0], march[:, -1] = (np.float32(border),) * 4
        if code.ndim == 3:
            march[:, :, 0], march[:, :, -1] = np.float32(border), np.float32(border)
    return march


def linear_indices(cells: np.ndarray, padded_shape: tuple[int, ...], shift: int) -> np.ndarray:
    """Linear indices into the padded grid of ``(N, dims)`` cell coordinates (or offsets,
    ``shift = 0``; cells of the unpadded grid use ``shift = 1``)."""
    cells = np.asarray(cells)
    strides = (padded_shape[1] * padded_shape[2], padded_shape[2], 1)
    dims = cells.shape[-1]
    index = np.zeros(cells.shape[:-1], dtype=np.int64)
    for axis in range(dims):  # per column: an integer matrix product has no BLAS and cost 10x more
        index += (cells[..., axis].astype(np.int64) + (shift if axis < 2 or dims == 3 else 0)) * strides[axis]
    return index.astype(np.int32)
