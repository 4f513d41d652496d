"""Depth-sensor noise models shared by the simulated depth camera and grid-level observation.

One interface, :class:`SensorNoise`, perturbs depth measurements (metres) with a seedable
generator, from presets or explicit parameters:

* axial noise, a Gaussian with ``sigma(z) = axial_a + axial_b * (z - axial_c)**2`` (the
  quadratic model of structured-light sensors fitted by Nguyen, Izadi and Lovell, 2012);
* lateral noise: each pixel takes the depth of a neighbour offset by a rounded Gaussian of
  ``lateral_px`` pixels (image input only);
* missing depth beyond ``[min_range_m, max_range_m]``, at grazing angles (incidence above
  ``grazing_deg``), next to depth edges (jumps above ``edge_jump_m`` within ``edge_px`` pixels),
  and at random (``dropout``).

Presets: ``ideal`` (no change), ``kinect_v1`` (0.5-4.0 m, the published quadratic axial model,
0.8 px lateral), ``astra`` (0.6-8.0 m, larger axial noise at range). The preset numbers are
approximations from published characterisations, not calibrations of a particular unit.
Imports no ROS and no open3d.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["PRESETS", "SensorNoise", "sensor_noise"]


@dataclass(frozen=True)
class SensorNoise:
    """Parameters of a depth-noise model (see the module docstring); all zero/inf = ideal."""

    name: str = "ideal"
    axial_a: float = 0.0
    axial_b: float = 0.0
    axial_c: float = 0.0
    lateral_px: float = 0.0
    min_range_m: float = 0.0
    max_range_m: float = math.inf
    grazing_deg: float = 90.0
    edge_jump_m: float = math.inf
    edge_px: int = 0
    dropout: float = 0.0

    def __post_init__(self) -> None:
        for name in ("axial_a", "axial_b", "lateral_px", "min_range_m", "dropout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"noise: {name} must be finite and >= 0, got {value}")
        if not self.dropout <= 1.0:
            raise ValueError(f"noise: dropout must lie in [0, 1], got {self.dropout}")
        if not self.max_range_m > self.min_range_m:
            raise ValueError(f"noise: max_range_m ({self.max_range_m}) must exceed min_range_m ({self.min_range_m})")
        if not 0.0 < self.grazing_deg <= 90.0:
            raise ValueError(f"noise: grazing_deg must lie in (0, 90], got {self.grazing_deg}")
        if self.edge_px < 0 or not self.edge_jump_m > 0:
            raise ValueError(f"noise: edge_px must be >= 0 and edge_jump_m > 0, got {self.edge_px}, {self.edge_jump_m}")

    @property
    def is_ideal(self) -> bool:
        return self == replace(IDEAL, name=self.name)

    def axial_sigma(self, depth_m: np.ndarray) -> np.ndarray:
        """Standard deviation [m] of the axial noise at depth ``depth_m``."""
        z = np.asarray(depth_m, dtype=np.float64)
        return self.axial_a + self.axial_b * (z - self.axial_c) ** 2

    def perturb_ranges(
        self, depth_m: np.ndarray, rng: np.random.Generator, cos_incidence: np.ndarray | None = None
    ) -> np.ndarray:
        """Noisy copy of depths of any shape (0 or NaN = no return, kept as 0): range limits,
        grazing angles (when ``cos_incidence``, the cosine between ray and surface normal, is
        given), random dropouts and axial noise. Returns ``float64``; 0 = no return."""
        depth = np.array(depth_m, dtype=np.float64, copy=True)
        valid = np.isfinite(depth) & (depth > 0)
        valid &= (depth >= self.min_range_m) & (depth <= self.max_range_m)
        if cos_incidence is not None and self.grazing_deg < 90.0:
            valid &= np.abs(np.asarray(cos_incidence)) >= math.cos(math.radians(self.grazing_deg))
        if self.dropout > 0:
            valid &= rng.random(depth.shape) >= self.dropout
        if self.axial_a > 0 or self.axial_b > 0:
            depth = depth + rng.standard_normal(depth.shape) * self.axial_sigma(np.where(valid, depth, 0.0))
        depth[~valid | ~(depth > 0)] = 0.0
        return depth

    def apply_image(
        self, depth_m: np.ndarray, rng: np.random.Generator, cos_incidence: np.ndarray | None = None
    ) -> np.ndarray:
        """Noisy ``float32`` copy of a depth image: edge and lateral noise, then :meth:`perturb_ranges`."""
        depth = np.where(np.isfinite(depth_m), np.asarray(depth_m, dtype=np.float64), 0.0)
        height, width = depth.shape
        if self.edge_px > 0 and math.isfinite(self.edge_jump_m):
            near_edge = np.zeros(depth.shape, dtype=bool)
            for axis in (0, 1):
                jump = np.abs(np.diff(depth, axis=axis)) > self.edge_jump_m
                pad = [(0, 0), (0, 0)]
                pad[axis] = (0, 1)
                edge = np.pad(jump, pad) | np.pad(jump, [(p[1], p[0]) for p in pad])
                for shift in range(1, self.edge_px):
                    edge |= np.roll(edge, shift, axis=axis) | np.roll(edge, -shift, axis=axis)
                near_edge |= edge
            depth[near_edge] = 0.0
        if self.lateral_px > 0:
            rows = np.arange(height)[:, None] + np.rint(rng.normal(0.0, self.lateral_px, depth.shape)).astype(int)
            cols = np.arange(width)[None, :] + np.rint(rng.normal(0.0, self.lateral_px, depth.shape)).astype(int)
            depth = depth[np.clip(rows, 0, height - 1), np.clip(cols, 0, width - 1)]
            if cos_incidence is not None:
                cos_incidence = np.asarray(cos_incidence)[np.clip(rows, 0, height - 1), np.clip(cols, 0, width - 1)]
        return self.perturb_ranges(depth, rng, cos_incidence).astype(np.float32)


IDEAL = SensorNoise()
#: Published-model approximations (see the module docstring).
PRESETS: dict[str, SensorNoise] = {
    "ideal": IDEAL,
    "kinect_v1": SensorNoise(
        "kinect_v1", axial_a=0.0012, axial_b=0.0019, axial_c=0.4, lateral_px=0.8, min_range_m=0.5,
        max_range_m=4.0, grazing_deg=75.0, edge_jump_m=0.05, edge_px=2, dropout=0.01,
    ),
    "astra": SensorNoise(
        "astra", axial_a=0.0015, axial_b=0.0030, axial_c=0.4, lateral_px=1.0, min_range_m=0.6,
        max_range_m=8.0, grazing_deg=72.0, edge_jump_m=0.05, edge_px=2, dropout=0.02,
    ),
}  # fmt: skip


def sensor_noise(name: str) -> SensorNoise:
    """The preset called ``name``.

    Raises:
        ValueError: an unknown preset (the known ones are named).
    """
    if name not in PRESETS:
        raise ValueError(f"noise preset {name!r} is unknown; expected one of {sorted(PRESETS)}")
    return PRESETS[name]
