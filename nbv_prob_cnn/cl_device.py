"""The process-wide OpenCL device, context and queue (shared by every kernel).

A GPU is preferred when present, otherwise the CPU through pocl. Set ``NBV_OPENCL_DEVICE``
to a substring of a device name to choose one explicitly.
"""

from __future__ import annotations

import functools
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class ClRuntime:
    cl: Any  # the pyopencl module
    device: Any  # pyopencl.Device
    context: Any  # pyopencl.Context
    queue: Any  # pyopencl.CommandQueue

    @property
    def has_fp64(self) -> bool:
        return "cl_khr_fp64" in self.device.extensions

    def build(self, source_file: Path, options: tuple[str, ...] = ()):
        """Compile an OpenCL source file for this device."""
        return self.cl.Program(self.context, source_file.read_text()).build(options=list(options))


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


@functools.lru_cache(maxsize=1)
def cl_runtime() -> ClRuntime:
    """Create (once) and return the OpenCL runtime.

    Raises:
        RuntimeError: no usable OpenCL device.
    """
    import pyopencl as cl

    device = _pick_device(cl)
    context = cl.Context([device])
    return ClRuntime(cl, device, context, cl.CommandQueue(context))


@functools.lru_cache(maxsize=1)
def opencl_available() -> bool:
    """True if pyopencl imports and a device can be opened (warns once otherwise)."""
    try:
        cl_runtime()
    except Exception as exc:  # noqa: BLE001 - any failure means "not available"
        warnings.warn(f"OpenCL unavailable, falling back to numpy: {exc}", stacklevel=2)
        return False
    return True
