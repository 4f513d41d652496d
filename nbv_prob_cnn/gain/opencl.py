"""OpenCL backend of the ray gain: one kernel (``raycast.cl``) for every method, on the
device of :mod:`nbv_prob_cnn.cl_device` (a GPU if present, else the CPU through pocl)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from nbv_prob_cnn.cl_device import cl_runtime

KERNEL_SOURCE = Path(__file__).with_name("raycast.cl")
MODES = {"prob": 0, "ig": 1}

#: Cell codes read by the kernel.
CODE_EMPTY = -1.0
CODE_OCCUPIED = -2.0


def encode_grid(state: np.ndarray, prob: np.ndarray | None) -> np.ndarray:
    """One float per cell: the probability of unknown cells, -1 empty, -2 occupied."""
    code = np.where(state == 1, np.float32(CODE_OCCUPIED), np.float32(CODE_EMPTY))
    if prob is None:
        return np.where(state == -1, np.float32(0.0), code).astype(np.float32)
    return np.where(state == -1, prob, code).astype(np.float32)


class OpenCLRayCaster:
    """Compiled kernel plus cached buffers for one OpenCL device."""

    def __init__(self) -> None:
        runtime = cl_runtime()
        cl = self._cl = runtime.cl
        self.device, self.context, self.queue = runtime.device, runtime.context, runtime.queue
        self._kernel = cl.Kernel(runtime.build(KERNEL_SOURCE), "ray_gain")
        self._offset_cache: dict[tuple, object] = {}

    def _offsets_buffer(self, offsets: np.ndarray):
        key = (offsets.shape, offsets.tobytes())
        buf = self._offset_cache.get(key)
        if buf is None:
            if len(self._offset_cache) > 8:
                self._offset_cache.clear()
            flat = np.zeros(offsets.shape[:2] + (3,), dtype=np.int16)
            flat[..., : offsets.shape[2]] = offsets
            mf = self._cl.mem_flags
            buf = self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(flat))
            self._offset_cache[key] = buf
        return buf

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
        cl = self._cl
        mf = cl.mem_flags
        shape3 = tuple(code.shape) + (1,) * (3 - code.ndim)
        n, r = origins.shape[0], offsets.shape[0]
        out = np.empty((n, r), dtype=np.float32)
        if n == 0:
            return out
        origins3 = np.zeros((n, 3), dtype=np.int32)
        origins3[:, : origins.shape[1]] = origins
        code_buf = cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(code))
        origin_buf = cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=origins3)
        out_buf = cl.Buffer(self.context, mf.WRITE_ONLY, out.nbytes)
        dims = code.ndim
        self._kernel.set_args(
            code_buf,
            np.int32(shape3[0]),
            np.int32(shape3[1]),
            np.int32(shape3[2]),
            origin_buf,
            np.int32(n),
            self._offsets_buffer(offsets),
            np.int32(r),
            np.int32(offsets.shape[1]),
            np.int32(dims - 1),
            np.float32(1.0 / total_weight),
            np.float32(eps),
            np.int32(MODES[mode]),
            np.float32(min_range),
            out_buf,
        )
        cl.enqueue_nd_range_kernel(self.queue, self._kernel, (n * r,), None)
        cl.enqueue_copy(self.queue, out, out_buf)
        self.queue.finish()
        return out


@functools.lru_cache(maxsize=1)
def get_ray_caster() -> OpenCLRayCaster:
    """The process-wide OpenCL ray caster (built on first use)."""
    return OpenCLRayCaster()
