"""Device choice of :mod:`nbv_prob_cnn.basics.cl_device` with a stand-in pyopencl module (no OpenCL needed)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from nbv_prob_cnn.basics.cl_device import _pick_device

GPU, CPU = 4, 2


class _FakeCl:
    """Just what ``_pick_device`` uses of pyopencl; ``Program.build`` fails on the broken devices."""

    device_type = SimpleNamespace(GPU=GPU, CPU=CPU)

    def __init__(self, devices: list[tuple[str, int, bool]]) -> None:
        platform = SimpleNamespace(name="Fake CL", version="OpenCL 3.0 fake")
        self.devices = [SimpleNamespace(name=n, type=t, works=w, platform=platform) for n, t, w in devices]
        self.built: list[str] = []
        fake = self

        class Program:
            def __init__(self, context, source: str) -> None:
                self.device = context.device

            def build(self) -> None:
                fake.built.append(self.device.name)
                if not self.device.works:
                    raise RuntimeError("clBuildProgram failed: error: unknown target CPU 'generic'")

        self.Program = Program

    def Context(self, devices):  # noqa: N802 - pyopencl's name
        return SimpleNamespace(device=devices[0])

    def get_platforms(self):
        return [SimpleNamespace(get_devices=lambda: self.devices)]


def test_gpu_first_then_the_first_device_that_compiles(monkeypatch):
    monkeypatch.delenv("NBV_OPENCL_DEVICE", raising=False)
    cl = _FakeCl([("pip-pocl cpu", CPU, False), ("debian-pocl cpu", CPU, True), ("gpu", GPU, True)])
    assert _pick_device(cl).name == "gpu"
    cl = _FakeCl([("pip-pocl cpu", CPU, False), ("debian-pocl cpu", CPU, True)])
    assert _pick_device(cl).name == "debian-pocl cpu"
    assert cl.built == ["pip-pocl cpu", "debian-pocl cpu"]


def test_no_device_that_compiles_names_each_failure_and_the_fix(monkeypatch):
    monkeypatch.delenv("NBV_OPENCL_DEVICE", raising=False)
    with pytest.raises(RuntimeError, match=r"pip-pocl cpu .*unknown target CPU.*pocl-opencl-icd"):
        _pick_device(_FakeCl([("pip-pocl cpu", CPU, False)]))
    with pytest.raises(RuntimeError, match="no OpenCL device found"):
        _pick_device(_FakeCl([]))


def test_nbv_opencl_device_restricts_the_choice(monkeypatch):
    cl = _FakeCl([("debian-pocl cpu", CPU, True), ("gpu", GPU, True)])
    monkeypatch.setenv("NBV_OPENCL_DEVICE", "DEBIAN")
    assert _pick_device(cl).name == "debian-pocl cpu"
    monkeypatch.setenv("NBV_OPENCL_DEVICE", "nvidia")
    with pytest.raises(RuntimeError, match="matches no OpenCL device"):
        _pick_device(cl)
