"""Gain variants: the paper's equations (``"paper"``, docs/method.md: gain, candidate views, the default) and the host
choices of the authors' published code (``"original"``), for the same kernel.

``"original"`` reproduces differences 1–4 and 7 of docs/original_code.md (which explains each,
with the paper's equation beside the code's choice):

1. range: samples ``t = 0 .. N - 1`` with ``N = floor((1 - 2π/64) · R_max)`` (21 on 3DU, 115 on
   2D/3DT) instead of ``t = 0 .. R_max``;
2. weights: ``min((t / f)^ν, 1)`` with ``f = 8`` (half the authors' view-cube resolution 16)
   instead of ``t^ν``;
3. CNN and oracle maps: an unknown sample counts ``(1 − p_t) · Pr(r_t)`` instead of ``Pr(r_t)``
   (the constant-``P0`` map of ``prob_ig`` keeps ``Pr(r_t)``: the original feeds ``P0`` as an
   a-priori occlusion, not as the cell's occupancy);
4. view gain: ``Σ_h hits_h / Σ_h (hits_h + miss_h)`` over the view's rays (for the probabilistic
   gain the mean ray gain, every ray's ``hits + miss`` being the same) instead of ``Σ_h G_r``;
7. ``ig``: a ray scores ``w_t / (Σ_{i<t} w_i + 1)`` at its first non-empty sample ``t`` if it is
   unknown (``0.01 / (Σ_{i<t} w_i + 1)`` below the minimum range of 5 cells, 0 if occupied);
   a ray that leaves the grid or ends unblocked has ``hits + miss = Σ_t w_t``.

Differences 5–6 (the authors' ray and orientation sets) are not part of the variant; in 3D their
ray set is the paper's ``N_rays = 16`` cube (``--n-rays 16``).
"""

from __future__ import annotations

import math

import numpy as np

#: Gain variants, default first.
GAIN_VARIANTS = ("paper", "original")
#: ``f`` of the original weights ``min((t / f)^ν, 1)``: half of its view-cube resolution 16.
ORIGINAL_FOCAL = 8.0
#: Range factor of the original host: ``(1 − 2π / (16 · 4)) · R_max``.
ORIGINAL_RANGE_FACTOR = 1.0 - 2.0 * math.pi / (16 * 4)
#: Minimum range (cells) of the original non-probabilistic ``ig``.
ORIGINAL_IG_MIN_RANGE = 5.0
#: Hits of an unknown first non-empty sample closer than the minimum range (original ``ig``).
ORIGINAL_NEAR_HIT = 0.01


def check_variant(variant: str) -> str:
    """``variant`` if it is one of :data:`GAIN_VARIANTS`, else a ValueError naming them."""
    if variant not in GAIN_VARIANTS:
        raise ValueError(f"gain variant: expected one of {GAIN_VARIANTS}, got {variant!r}")
    return variant


def sample_count(variant: str, r_max: int) -> int:
    """Samples per ray: ``R_max + 1`` (paper, ``t = 0 .. R_max``) or
    ``floor((1 − 2π/64) · R_max)`` (original, ``t = 0 .. N − 1``; at least 1)."""
    if check_variant(variant) == "paper":
        return int(r_max) + 1
    # the original computes the range in double, stores it as a float, then truncates it
    return max(1, int(np.float32(ORIGINAL_RANGE_FACTOR * r_max)))


def sample_weights(variant: str, n_samples: int, dims: int) -> np.ndarray:
    """Weight of sample ``t = 0 .. n_samples − 1``, float64: ``t^ν`` (paper) or
    ``min((t / f)^ν, 1)`` (original), ``ν = 1`` in 2D, 2 in 3D."""
    t = np.arange(n_samples, dtype=np.float64)
    nu = dims - 1
    if check_variant(variant) == "paper":
        return t**nu
    return np.minimum((t / ORIGINAL_FOCAL) ** nu, 1.0)


def ig_min_range(variant: str, sensor_min_range: float) -> float:
    """Minimum range of ``ig``: the sensor's (paper) or :data:`ORIGINAL_IG_MIN_RANGE` (original)."""
    return float(sensor_min_range) if check_variant(variant) == "paper" else ORIGINAL_IG_MIN_RANGE


def uses_free_hits(variant: str, probability: str | None) -> bool:
    """Item 3: whether an unknown sample counts ``(1 − p_t) · Pr(r_t)``: under ``original`` for the
    maps the original feeds as occupancy (``"cnn"``, ``"oracle"``), not for ``"constant"`` ``P0``."""
    return check_variant(variant) == "original" and probability in ("cnn", "oracle")
