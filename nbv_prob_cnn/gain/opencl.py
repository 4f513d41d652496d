"""OpenCL backend of the ray gain: one kernel (``raycast.cl``) for every method.

Runs on a GPU when one is present, otherwise on the CPU through pocl. Select a device with
the environment variable ``NBV_OPENCL_DEVICE`` (a substring of the device name) if needed.
"""

from __future__ import annotations

import functools
import os
import warnings
from pathlib import Path

import numpy as np

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


def _pick_device(cl):
    wanted = os.environ.get("NBV_OPENCL_DEVICE", "").lower()
    devices = [d for p in cl.get_platforms() for d in p.get_devices()]
    if not devices:
        raise RuntimeError("no OpenCL device found (install pyopencl[pocl] for the CPU)")
    if wanted:
        matching = [d for d in devices if wanted in d.name.lower()]
        if not matching:
            raise RuntimeError(f"NBV_OPENCL_DEVICE={wanted!r} matches none of {[d.name for d in devices]}")
        return matching[0]
    gpus = [d for d in devices if d.type & cl.device_type.GPU]
    return (gpus or devices)[0]


class OpenCLRayCaster:
    """Compiled kernel plus cached buffers for one OpenCL device."""

    def __init__(self) -> None:
        import pyopencl as cl

        self._cl = cl
        self.device = _pick_device(cl)
        self.context = cl.Context([self.device])
        self.queue = cl.CommandQueue(self.context)
        self.program = cl.Program(self.context, KERNEL_SOURCE.read_text()).build()
        self._kernel = cl.Kernel(self.program, "ray_gain")
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


@functools.lru_cache(maxsize=1)
def opencl_available() -> bool:
    """True if pyopencl imports and a device can run the kernel."""
    try:
        get_ray_caster()
    except Exception as exc:  # noqa: BLE001 - any failure means "not available"
        warnings.warn(f"OpenCL unavailable, falling back to the numpy backend: {exc}", stacklevel=2)
        return False
    return True
