"""Depth sensor parameters (docs/method.md: sensor, parameters). Re-exported by :mod:`nbv_prob_cnn.basics.camera`."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Sensor:
    """Depth sensor parameters. Ranges are in cells."""

    hfov_deg: float
    vfov_deg: float | None
    r_max: int
    min_range: float = 0.0
    width_px: int = 0
    height_px: int = 0
    focal_px: float = 0.0
