"""The process-wide OpenCL device, context and queue (shared by every kernel).

A GPU is preferred when present, otherwise the CPU through pocl; a device is only taken once a
trivial kernel compiles for it (an ICD may list a device it cannot compile for). Set
``NBV_OPENCL_DEVICE`` to a substring of a device name to choose among the matching ones.
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


_PROBE_KERNEL = "__kernel void probe(__global float *a) { a[get_global_id(0)] *= 2.0f; }"
INSTALL_HINT = (
    "install pyopencl[pocl] for the CPU; where its bundled pocl cannot compile for this CPU "
    '("unknown target CPU"), the Debian package pocl-opencl-icd (launch_scripts/setup.sh does this)'
)


def _compile_error(cl, device) -> str:
    """Empty when a trivial kernel compiles for ``device``, else the reason (a broken ICD, e.g. a
    pocl whose LLVM does not know this CPU, lists a device that cannot build anything)."""
    try:
        cl.Program(cl.Context([device]), _PROBE_KERNEL).build()
    except Exception as exc:  # noqa: BLE001 - any failure means "not usable"
        reason = " ".join(str(exc).split())[:300]
        return f"{device.name} ({device.platform.name} {device.platform.version}): {reason}"
    return ""


def _pick_device(cl):
    wanted = os.environ.get("NBV_OPENCL_DEVICE", "").lower()
    devices = [d for p in cl.get_platforms() for d in p.get_devices()]
    if not devices:
        raise RuntimeError(f"no OpenCL device found ({INSTALL_HINT})")
    if wanted:
        devices = [d for d in devices if wanted in d.name.lower()]
        if not devices:
            raise RuntimeError(f"NBV_OPENCL_DEVICE={wanted!r} matches no OpenCL device")
    gpus = [d for d in devices if d.type & cl.device_type.GPU]
    errors = []
    for device in gpus + [d for d in devices if d not in gpus]:
        error = _compile_error(cl, device)
        if not error:
            return device
        errors.append(error)
    raise RuntimeError("no OpenCL device compiles a kernel: " + "; ".join(errors) + f" ({INSTALL_HINT})")


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
