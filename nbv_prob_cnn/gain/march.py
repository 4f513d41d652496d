"""What a gain launch marches besides the grid and the origins, for both backends: the rays' sample
table, its weight normaliser and the kernel's settings (:class:`RayMarch`), and the tables of the
optional exact-traversal sampling and ``"returns"`` sensor model (:class:`MarchOptions`,
:mod:`nbv_prob_cnn.gain.sampling`). Both are built from a
:class:`~nbv_prob_cnn.gain.settings.GainSettings`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.gain.directions import distance_weights, grouped_sample_offsets, sample_offsets
from nbv_prob_cnn.gain.sampling import GainSensor, RaySamples, occupancy_normals, ray_samples
from nbv_prob_cnn.gain.settings import GainSettings
from nbv_prob_cnn.gain.variant import sample_count, sample_weights


@dataclass(frozen=True)
class MarchOptions:
    """The optional modes of a launch (docs/sensing.md; the paper's variant only).

    Attributes:
        samples: the rays' :class:`~nbv_prob_cnn.gain.sampling.RaySamples` (their offsets are the
            launch's ``offsets``); ``"exact"`` builds ``GAIN_EXACT``.
        min_range: minimum range (cells) of the exact tables' per-ray first return (``ig``: its
            minimum range; the ``"returns"`` model: the sensor's).
        sensor: the ``"returns"`` model's sensor (builds ``GAIN_SENSOR``), or None.
        directions: ``(R, dims)`` ray directions (the grazing test), with ``sensor``.
        normals: ``(dims, *shape)`` surface normals of the grid
            (:func:`~nbv_prob_cnn.gain.sampling.occupancy_normals`), with ``sensor``.
    """

    samples: RaySamples
    min_range: float = 0.0
    sensor: GainSensor | None = None
    directions: np.ndarray | None = None
    normals: np.ndarray | None = None

    @property
    def exact(self) -> bool:
        return self.samples.sampling == "exact"

    @property
    def flags(self) -> tuple[bool, bool]:
        """``(GAIN_EXACT, GAIN_SENSOR)`` of the program."""
        return self.exact, self.sensor is not None

    def bound_options(self) -> MarchOptions | None:
        """The options of the coarse-to-fine bounds: the paper's gain on the same samples (an
        upper bound of the ``"returns"`` gain: every cell counts at most its visibility), marched
        only as far as a sample has weight."""
        if not self.exact:
            return None
        cut = self.samples.weighted
        s = self.samples
        truncated = RaySamples(s.offsets[:, :cut], s.distance[:, :cut], np.minimum(s.counts, cut), s.weights[:, :cut],
                               s.total, s.sampling)  # fmt: skip
        return MarchOptions(truncated, self.min_range)


@dataclass(frozen=True, eq=False)
class RayMarch:
    """The constants of a gain launch.

    Attributes:
        offsets: ``(R, T, dims)`` int16 cell offsets of the rays' samples (the variant's range, or
            the table of ``options``).
        total_weight: the weight normaliser (``sum_t t^nu``; the original variant's weights; the
            table's total).
        mode: the kernel's mode, ``prob``, ``ig`` or ``prob_free``
            (:attr:`~nbv_prob_cnn.gain.settings.GainSettings.kernel_mode`).
        eps: early-stop tolerance of ``Pr`` (0: exact).
        min_range: minimum range in cells.
        variant: gain variant (:mod:`nbv_prob_cnn.gain.variant`), a build option of the program.
        options: the optional modes' tables, or None (the paper's gain on rounded samples).
        surface: the surface blend (:attr:`~nbv_prob_cnn.gain.settings.GainSettings.surface`).
    """

    offsets: np.ndarray
    total_weight: float
    mode: str = "prob"
    eps: float = 0.0
    min_range: float = 0.0
    variant: str = "paper"
    options: MarchOptions | None = None
    surface: float = 0.0

    @property
    def program(self) -> tuple[str, bool, bool]:
        """The program's build options: ``(variant, GAIN_EXACT, GAIN_SENSOR)``."""
        exact, sensor = self.options.flags if self.options is not None else (False, False)
        return self.variant, exact, sensor


def march_options(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    settings: GainSettings,
    normals: np.ndarray | None = None,
) -> MarchOptions | None:
    """The :class:`MarchOptions` of ``settings.sensor`` and ``settings.sampling``, or None for the
    paper's gain on rounded samples (the default path, unchanged). ``normals``: the grid's
    :func:`~nbv_prob_cnn.gain.sampling.occupancy_normals` when already computed (the sensor model)."""
    if not settings.marches_table:
        return None
    sensor, min_range = settings.sensor, settings.min_range
    if settings.mode == "ig" and sensor is not None:  # ig: the first unknown cell is the return
        min_range, sensor = sensor.min_range, None
    if sensor is None:
        return MarchOptions(ray_samples(directions, r_max, settings.sampling), float(min_range))
    samples = ray_samples(directions, r_max, settings.sampling, sensor.reach(state.shape))
    normals = occupancy_normals(state, prob) if normals is None else normals
    return MarchOptions(samples, sensor.min_range, sensor, directions, normals)


def ray_march(
    dims: int,
    directions: np.ndarray,
    r_max: int,
    settings: GainSettings,
    options: MarchOptions | None = None,
    groups: int = 1,
) -> RayMarch:
    """The :class:`RayMarch` of ``settings`` on a ``dims``-dimensional grid: the samples of
    ``options`` when given, else those of the variant's range with its weights. ``groups``: the
    directions are that many sets of rays, one per origin, whose paper-variant tables are kept
    (:func:`~nbv_prob_cnn.gain.directions.grouped_sample_offsets`)."""
    if options is not None:
        offsets, total, min_range = options.samples.offsets, options.samples.total, options.min_range
    elif settings.variant == "paper":
        offsets = (
            sample_offsets(directions, r_max) if groups == 1 else grouped_sample_offsets(directions, r_max, groups)
        )
        total = float(distance_weights(r_max, dims).sum())
        min_range = settings.min_range
    else:
        n_samples = sample_count(settings.variant, r_max)
        offsets = sample_offsets(directions, n_samples - 1)
        total = float(sample_weights(settings.variant, n_samples, dims).sum())
        min_range = settings.min_range
    return RayMarch(offsets, total, settings.kernel_mode, settings.eps, min_range, settings.variant, options,
                    float(settings.surface))  # fmt: skip
