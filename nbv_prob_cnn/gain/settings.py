"""How a gain is computed, apart from the grid, the rays and the origins: one frozen object that the
gain functions (:func:`~nbv_prob_cnn.gain.ray_gains`, :func:`~nbv_prob_cnn.gain.origin_view_gains`,
:func:`~nbv_prob_cnn.gain.best_origin_view`) take and pass on to both backends."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.gain.sampling import GainSensor, check_sampling
from nbv_prob_cnn.gain.variant import check_variant

#: Gain modes: probabilistic ray casting, or the non-probabilistic information gain.
GAIN_MODES = ("prob", "ig")
#: The surface methods' blend ``beta`` (``cnn_surface``, ``prob_surface``, ``omniscient_surface``;
#: docs/method.md#surface-gain): chosen by ``nbv study surface_blend`` (docs/evaluation.md#the-surface-gain).
DEFAULT_SURFACE_BLEND = 0.9


@dataclass(frozen=True)
class GainSettings:
    """The choices of a gain computation (docs/method.md#probabilistic-ray-casting-gain, docs/sensing.md).

    Attributes:
        mode: ``"prob"`` (equations (2)–(6)) or ``"ig"`` (non-probabilistic information gain: the
            first non-empty sample, weighted ``t^nu / sum t^nu``, if unknown and ``t >= min_range``).
        eps: OpenCL only: stop a ray once ``Pr(r_t) <= eps``. ``0`` is exact (a ray stops only when
            ``Pr`` is exactly 0: occupied cell or grid border). With ``eps > 0`` each ``G_r`` is
            under-estimated by less than ``eps`` (the remaining terms sum to at most ``Pr * sum_t t^nu``).
        min_range: ``mode="ig"`` only, minimum sensor range in cells.
        variant: ``"paper"`` (docs/method.md#probabilistic-ray-casting-gain) or ``"original"`` (the
            authors' host choices: range, weights, normalisation, ``ig``; :mod:`nbv_prob_cnn.gain.variant`).
        free_hits: ``variant="original"``, ``mode="prob"`` only: an unknown sample counts
            ``(1 - p_t) Pr(r_t)`` (the original's CNN and oracle maps).
        sensor: the ``"returns"`` sensor model (:class:`~nbv_prob_cnn.gain.sampling.GainSensor`,
            docs/sensing.md): an unknown cell counts by the probability that the sensor measures it;
            with ``mode="ig"`` only its minimum range replaces ``min_range``. None: the paper's.
        sampling: ``"rounded"`` (docs/method.md) or ``"exact"`` voxel traversal of the rays.
        surface: the surface blend ``beta`` in [0, 1] (docs/method.md#surface-gain), ``mode="prob"``
            and the paper's variant only: an unknown sample counts ``(1 - beta) + beta p`` times
            what it counts in the paper's gain. ``0`` is the paper's gain (bit for bit), ``1`` the
            expected number of unknown cells at which the ray's return lands (the new surface).

    ``sensor``, ``sampling="exact"`` and ``surface`` go with the paper's variant only.

    Raises:
        ValueError: a setting out of its range, naming it.
    """

    mode: str = "prob"
    eps: float = 0.0
    min_range: float = 0.0
    variant: str = "paper"
    free_hits: bool = False
    sensor: GainSensor | None = None
    sampling: str = "rounded"
    surface: float = 0.0

    def __post_init__(self) -> None:
        if self.mode not in GAIN_MODES:
            raise ValueError(f"mode: expected one of {GAIN_MODES}, got {self.mode!r}")
        if not (np.isfinite(self.eps) and 0.0 <= self.eps < 1.0):
            raise ValueError(f"eps: expected a tolerance in [0, 1), got {self.eps!r}")
        if not np.isfinite(self.min_range):
            raise ValueError(f"min_range: expected a finite range in cells, got {self.min_range!r}")
        check_variant(self.variant)
        if self.free_hits and (self.variant != "original" or self.mode != "prob"):
            raise ValueError(
                f"free_hits: only with variant='original' and mode='prob', got {self.variant!r}, {self.mode!r}"
            )
        check_sampling(self.sampling)
        if self.sensor is not None and not isinstance(self.sensor, GainSensor):
            raise ValueError(f"sensor: expected a GainSensor or None, got {type(self.sensor).__name__}")
        if not (isinstance(self.surface, (int, float, np.floating)) and 0.0 <= float(self.surface) <= 1.0):
            raise ValueError(f"surface: expected a blend in [0, 1] (0: the paper's gain), got {self.surface!r}")
        if self.surface and (self.mode != "prob" or self.variant != "paper"):
            raise ValueError(
                f"surface: only with mode='prob' and the paper's variant, got {self.mode!r}, {self.variant!r}"
            )
        if self.marches_table and self.variant != "paper":
            raise ValueError(f"sensor/sampling: only with the paper's gain variant, got {self.variant!r}")

    @property
    def kernel_mode(self) -> str:
        """The kernels' mode: ``prob``, ``ig`` or ``prob_free`` (``free_hits``)."""
        return "prob_free" if self.free_hits else self.mode

    @property
    def marches_table(self) -> bool:
        """Whether the rays march a :class:`~nbv_prob_cnn.gain.sampling.RaySamples` table (a sensor
        model or exact sampling) rather than the paper's gain on rounded samples."""
        return self.sensor is not None or self.sampling != "rounded"


#: The paper's gain: probabilistic, exact, rounded samples, no sensor model.
PAPER_GAIN = GainSettings()
