"""OpenCL backend of the ray gain: one ray-marching function (``raycast.cl``) for every method,
on the device of :mod:`nbv_prob_cnn.cl_device` (a GPU if present, else the CPU through pocl).

Two kernels call it: ``view_gain`` sums the ray gains of each origin into its candidate views
in local memory (the planners' path: no per-ray gains in global memory), ``ray_gain`` returns
per-ray gains (poses with their own frusta).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from scipy.ndimage import distance_transform_cdt

from nbv_prob_cnn.cl_device import cl_runtime

KERNEL_SOURCE = Path(__file__).with_name("raycast.cl")
MODES = {"prob": 0, "ig": 1}

#: Cell codes read by the kernel.
CODE_EMPTY = -1.0
CODE_OCCUPIED = -2.0

#: Largest empty-space jump encoded in the grid (cells).
MAX_SKIP = 1 << 20

#: Origins per work-group in ``view_gain`` (one work-item each).
VIEW_GAIN_LOCAL_SIZE = 16
#: Origins per ``view_gain`` launch (bounds the device output buffer).
VIEW_GAIN_ORIGINS_PER_LAUNCH = 1 << 17


def encode_grid(state: np.ndarray, prob: np.ndarray | None) -> np.ndarray:
    """One float per cell: the probability of unknown cells, -1 empty, -2 occupied."""
    code = np.where(state == 1, np.float32(CODE_OCCUPIED), np.float32(CODE_EMPTY))
    if prob is None:
        return np.where(state == -1, np.float32(0.0), code).astype(np.float32)
    return np.where(state == -1, prob, code).astype(np.float32)


def march_grid(code: np.ndarray) -> np.ndarray:
    """The grid the kernels march: ``code`` (from :func:`encode_grid`) as a 3D C-ordered array
    with one occupied cell of padding on each side of every axis the rays move along (2D grids
    get a trailing axis of size 1, not padded). Occupied cells (and the padding) become -1;
    known-empty cells become ``-1 - d`` with ``d`` the Chebyshev distance to the nearest
    non-empty cell (capped at :data:`MAX_SKIP`): the first samples of every ray from there are
    empty (see :func:`group_first_samples`)."""
    code3 = code if code.ndim == 3 else code[:, :, None]
    pad = ((1, 1), (1, 1), (1, 1) if code.ndim == 3 else (0, 0))
    padded = np.pad(code3, pad, constant_values=np.float32(CODE_OCCUPIED))
    if padded.size >= 2**31:
        raise ValueError(f"grid of shape {code.shape} too large for 32-bit cell indices")
    empty = padded == np.float32(CODE_EMPTY)
    distance = distance_transform_cdt(empty if code.ndim == 3 else empty[:, :, 0], metric="chessboard")
    distance = np.minimum(distance, MAX_SKIP).reshape(padded.shape)
    march = np.where(empty, -1.0 - distance, np.where(padded == np.float32(CODE_OCCUPIED), -1.0, padded))
    return np.ascontiguousarray(march, dtype=np.float32)


def linear_indices(cells: np.ndarray, padded_shape: tuple[int, int, int], shift: int) -> np.ndarray:
    """Linear indices into the padded grid of ``(N, dims)`` cell coordinates (or offsets,
    ``shift = 0``; cells of the unpadded grid use ``shift = 1``)."""
    strides = np.array([padded_shape[1] * padded_shape[2], padded_shape[2], 1], dtype=np.int64)
    dims = cells.shape[-1]
    shifts = np.array([shift, shift, shift if dims == 3 else 0][:dims], dtype=np.int64)
    return ((cells.astype(np.int64) + shifts) @ strides[:dims]).astype(np.int32)


def view_table(membership: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``(R, V)`` 0/1 ray-in-view matrix as compressed rows per view: ``start`` ``(V + 1,)``
    and ``rays`` (ascending ray indices of view ``w`` in ``rays[start[w]:start[w + 1]]``)."""
    member = np.asarray(membership) != 0
    counts = member.sum(axis=0)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    rays = np.nonzero(member.T)[1].astype(np.int32)
    return start, rays


def group_first_samples(padded: np.ndarray, origin_index: np.ndarray, group: int) -> np.ndarray:
    """Per block of ``group`` consecutive origins, the first sample ``t`` worth reading on any of
    their rays: the smallest Chebyshev distance ``d`` from the block's origins to a non-empty
    cell (samples ``0 .. d - 1`` of every ray are within ``d - 1`` cells, hence empty). One
    start per work-group keeps the work-items' loops in step (vectorizable)."""
    values = padded.reshape(-1)[origin_index]
    distance = np.where(values <= -2.0, -1.0 - values, 0.0).astype(np.int32)
    padding = -distance.size % group
    distance = np.concatenate([distance, np.zeros(padding, dtype=np.int32)]) if padding else distance
    return np.ascontiguousarray(distance.reshape(-1, group).min(axis=1), dtype=np.int32)


class OpenCLRayCaster:
    """Compiled kernels plus cached constant buffers for one OpenCL device."""

    def __init__(self) -> None:
        runtime = cl_runtime()
        cl = self._cl = runtime.cl
        self.device, self.context, self.queue = runtime.device, runtime.context, runtime.queue
        program = runtime.build(KERNEL_SOURCE)
        self._ray_kernel = cl.Kernel(program, "ray_gain")
        self._view_kernel = cl.Kernel(program, "view_gain")
        self._cache: dict[tuple, object] = {}

    def _constant(self, array: np.ndarray):
        """A read-only device copy of ``array``, cached by content."""
        array = np.ascontiguousarray(array)
        key = (array.dtype.str, array.shape, array.tobytes())
        buf = self._cache.get(key)
        if buf is None:
            if len(self._cache) > 16:
                self._cache.clear()  # callers hold the buffers they are using
            mf = self._cl.mem_flags
            buf = self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=array)
            self._cache[key] = buf
        return buf

    def _common(self, code: np.ndarray, origins: np.ndarray, offsets: np.ndarray):
        """Device grid, host grid, linear origins and device linear offsets ``(R, T)``."""
        cl, mf = self._cl, self._cl.mem_flags
        padded = march_grid(code)
        code_buf = cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=padded)
        origin_index = linear_indices(origins, padded.shape, shift=1)
        offset_index = linear_indices(offsets.reshape(-1, offsets.shape[2]), padded.shape, shift=0)
        return code_buf, padded, origin_index, self._constant(offset_index.reshape(offsets.shape[:2]))

    def run(
        self,
        code: np.ndarray,
        origins: np.ndarray,
        offsets: np.ndarray,
        total_weight: float,
        mode: str,
        eps: float,
        min_range: float,
    ) -> np.ndarray:
        """Ray gains ``(N, R)`` float32 for the encoded grid ``code``."""
        cl, mf = self._cl, self._cl.mem_flags
        n, r = origins.shape[0], offsets.shape[0]
        out = np.empty((n, r), dtype=np.float32)
        if n == 0:
            return out
        code_buf, _, origin_index, offset_buf = self._common(code, origins, offsets)
        origin_buf = cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=origin_index)
        out_buf = cl.Buffer(self.context, mf.WRITE_ONLY, out.nbytes)
        self._ray_kernel.set_args(
            code_buf, origin_buf, np.int32(n), offset_buf, np.int32(r), np.int32(offsets.shape[1]),
            np.int32(code.ndim - 1), np.float32(1.0 / total_weight), np.float32(eps), np.int32(MODES[mode]),
            np.float32(min_range), out_buf,
        )  # fmt: skip
        cl.enqueue_nd_range_kernel(self.queue, self._ray_kernel, (n * r,), None)
        cl.enqueue_copy(self.queue, out, out_buf)
        self.queue.finish()
        return out

    def run_views(
        self,
        code: np.ndarray,
        origins: np.ndarray,
        offsets: np.ndarray,
        membership: np.ndarray,
        total_weight: float,
        mode: str,
        eps: float,
        min_range: float,
        local_size: int = VIEW_GAIN_LOCAL_SIZE,
    ) -> np.ndarray:
        """View gains ``(N, V)`` float32: the ray gains of each origin summed over the rays of
        each view (``membership`` is the ``(R, V)`` 0/1 ray-in-view matrix)."""
        cl, mf = self._cl, self._cl.mem_flags
        n, r, v = origins.shape[0], offsets.shape[0], membership.shape[1]
        out = np.empty((n, v), dtype=np.float32)
        if n == 0:
            return out
        start, rays = view_table(membership)
        # local references keep every buffer alive until the queue has finished with it
        start_buf, rays_buf = self._constant(start), self._constant(rays)
        code_buf, padded, origin_index, offset_buf = self._common(code, origins, offsets)
        local_size = int(min(local_size, self.device.max_work_group_size))
        local_size = max(1, min(local_size, self.device.local_mem_size // (4 * r)))
        first_sample = group_first_samples(padded, origin_index, local_size)
        block = min(n, VIEW_GAIN_ORIGINS_PER_LAUNCH // local_size * local_size)
        origin_buf = cl.Buffer(self.context, mf.READ_ONLY, block * 4)
        first_buf = cl.Buffer(self.context, mf.READ_ONLY, -(-block // local_size) * 4)
        out_buf = cl.Buffer(self.context, mf.WRITE_ONLY, block * v * 4)
        kernel = self._view_kernel
        for begin in range(0, n, block):
            count = min(block, n - begin)
            cl.enqueue_copy(self.queue, origin_buf, origin_index[begin : begin + count])
            group = begin // local_size
            cl.enqueue_copy(self.queue, first_buf, first_sample[group : group + -(-count // local_size)])
            kernel.set_args(
                code_buf, origin_buf, np.int32(count), offset_buf, np.int32(r), np.int32(offsets.shape[1]),
                np.int32(code.ndim - 1), np.float32(1.0 / total_weight), np.float32(eps), np.int32(MODES[mode]),
                np.float32(min_range), start_buf, rays_buf, np.int32(v), first_buf,
                cl.LocalMemory(4 * r * local_size), out_buf,
            )  # fmt: skip
            groups = -(-count // local_size)
            cl.enqueue_nd_range_kernel(self.queue, kernel, (groups * local_size,), (local_size,))
            cl.enqueue_copy(self.queue, out[begin : begin + count], out_buf)
        self.queue.finish()
        return out


@functools.lru_cache(maxsize=1)
def get_ray_caster() -> OpenCLRayCaster:
    """The process-wide OpenCL ray caster (built on first use)."""
    return OpenCLRayCaster()
