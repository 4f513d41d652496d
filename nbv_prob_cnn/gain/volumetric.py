"""The field's volumetric gain formulations (Isler et al., ICRA 2016; Delmerico et al., Autonomous
Robots 2018; Kriegel et al.), on our ternary grid, as baselines (docs/method.md#volumetric-baselines).

Each is a per-ray quantity summed over the rays of a view (``average_entropy``: a ratio of two
sums). A ray marches the samples ``t = 1 .. r_max`` of :func:`~nbv_prob_cnn.gain.directions.sample_offsets`
(the paper's rounded samples, as our gain) and ends at the first known-occupied cell, its hit,
included; or at the grid's border (a ray that hits nothing).

The cells carry OctoMap's probabilities (:class:`OctoMapProbabilities`): a known-empty cell has the
clamped free probability, a known-occupied one the clamped occupied probability, an unknown cell the
prior (0.5) or, with ``prob``, the completion CNN's probability. A cell's entropy is
``H(p) = -p log2 p - (1 - p) log2 (1 - p)`` bits and its visibility the product of ``1 - p`` over the
cells before it on the ray.

Per ray:

* ``occlusion_aware``: ``Σ_t V_t H(p_t)`` over every cell marched (Isler's occlusion-aware gain);
* ``unobserved_voxel``: the same over the unknown cells only;
* ``rear_side_voxel``: 1 when the ray's hit follows an unknown cell (it would see the rear side of
  a surface seen before), else 0;
* ``proximity_count``: ``Σ max(0, d_max - d(x))`` over the unknown cells ``x`` marched, ``d(x)`` the
  distance in cells to the nearest known-occupied cell (unknown space near the surface counts most);
* ``average_entropy`` (Kriegel): per view, the entropy summed over the cells of its rays that hit
  something, over the number of those cells.

A plain numpy implementation (vectorised over origins and rays): the planners run it on a random
subset of origins (:data:`~nbv_prob_cnn.planners.methods.DOWNSAMPLED_ORIGINS`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt

from nbv_prob_cnn.gain.directions import sample_offsets
from nbv_prob_cnn.gain.reference import _sample_cells

#: The formulations of this module.
VOLUMETRIC_GAINS = ("occlusion_aware", "unobserved_voxel", "rear_side_voxel", "proximity_count", "average_entropy")

_CHUNK = 1024  # origins per block


@dataclass(frozen=True)
class OctoMapProbabilities:
    """How the ternary grid's cells read as OctoMap occupancy probabilities: OctoMap's default
    clamping thresholds for known cells (``clamping_thres_min`` 0.1192, ``clamping_thres_max``
    0.971), its prior 0.5 for unknown space; ``proximity_cells``: ``d_max`` of ``proximity_count``."""

    free: float = 0.1192
    occupied: float = 0.971
    prior: float = 0.5
    proximity_cells: float = 5.0

    def __post_init__(self) -> None:
        for name in ("free", "occupied", "prior"):
            value = getattr(self, name)
            if not 0.0 < value < 1.0:
                raise ValueError(f"{name}: expected a probability in (0, 1), got {value!r}")
        if not self.proximity_cells > 0:
            raise ValueError(f"proximity_cells: expected a positive distance, got {self.proximity_cells!r}")

    def cell_probabilities(self, state: np.ndarray, prob: np.ndarray | None) -> np.ndarray:
        """Per cell its occupancy probability (``prob`` in unknown cells, else the prior)."""
        p = np.where(state == 1, self.occupied, np.where(state == 0, self.free, self.prior))
        if prob is not None:
            p = np.where(state == -1, np.clip(prob, 1e-6, 1 - 1e-6), p)
        return p.astype(np.float64)


def entropy_bits(p: np.ndarray) -> np.ndarray:
    """Binary entropy in bits (0 at p = 0 or 1)."""
    p = np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -(p * np.log2(p) + (1 - p) * np.log2(1 - p))
    return np.nan_to_num(h, nan=0.0)


def volumetric_ray_terms(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    origins: np.ndarray,
    formulation: str,
    octomap: OctoMapProbabilities | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per origin and ray the formulation's value and, for ``average_entropy``, the number of cells
    it summed (the ratio's denominator; ones otherwise), each ``(N, R)`` float64.

    Raises:
        ValueError: an unknown formulation.
    """
    if formulation not in VOLUMETRIC_GAINS:
        raise ValueError(f"formulation: expected one of {VOLUMETRIC_GAINS}, got {formulation!r}")
    octomap = octomap or OctoMapProbabilities()
    p = octomap.cell_probabilities(state, prob)
    entropy = entropy_bits(p)
    if formulation == "proximity_count":
        occupied = state == 1
        distance = distance_transform_edt(~occupied) if occupied.any() else np.full(state.shape, np.inf)
        closeness = np.maximum(0.0, octomap.proximity_cells - distance)
    offsets = sample_offsets(directions, r_max)
    values = np.zeros((origins.shape[0], directions.shape[0]))
    counts = np.ones_like(values)
    flat_state, flat_p, flat_h = state.reshape(-1), p.reshape(-1), entropy.reshape(-1)
    for start in range(0, origins.shape[0], _CHUNK):
        block = slice(start, start + _CHUNK)
        shape = values[block].shape
        alive = np.ones(shape, dtype=bool)
        visible = np.ones(shape)
        previous_unknown = np.zeros(shape, dtype=bool)
        total = np.zeros(shape)
        cells = np.zeros(shape)
        if formulation == "average_entropy":
            counts[block] = 0.0  # a ray that hits nothing adds no cell
        for t in range(1, r_max + 1):
            inside, flat = _sample_cells(state.shape, origins[block], offsets[:, t])
            alive &= inside  # the border ends a ray without a hit
            code = np.where(alive, flat_state[flat], 0)
            unknown, hit = alive & (code == -1), alive & (code == 1)
            if formulation == "occlusion_aware":
                total += np.where(alive, visible * flat_h[flat], 0.0)
            elif formulation == "unobserved_voxel":
                total += np.where(unknown, visible * flat_h[flat], 0.0)
            elif formulation == "rear_side_voxel":
                total += hit & previous_unknown
            elif formulation == "proximity_count":
                total += np.where(unknown, closeness.reshape(-1)[flat], 0.0)
            else:  # average_entropy: the ray's cells so far; kept only if it hits
                total += np.where(alive, flat_h[flat], 0.0)
                cells += alive
            visible = np.where(alive, visible * (1.0 - flat_p[flat]), visible)
            previous_unknown = np.where(alive, unknown, previous_unknown)
            if formulation == "average_entropy":
                values[block] += np.where(hit, total, 0.0)
                counts[block] = np.where(hit, cells, counts[block])
            alive &= ~hit
            if not alive.any():
                break
        if formulation != "average_entropy":
            values[block] = total
    return values, counts


def volumetric_view_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    membership: np.ndarray,
    origins: np.ndarray,
    formulation: str,
    octomap: OctoMapProbabilities | None = None,
) -> np.ndarray:
    """``(N, V)`` view gains of ``formulation``: its rays' values summed over each view (``average_entropy``:
    the summed entropy over the summed cell count of the view's hitting rays, 0 without one)."""
    values, counts = volumetric_ray_terms(state, prob, directions, r_max, origins, formulation, octomap)
    member = np.asarray(membership, dtype=np.float64)
    gains = values @ member
    if formulation == "average_entropy":
        cells = counts @ member
        gains = np.where(cells > 0, gains / np.where(cells > 0, cells, 1.0), 0.0)
    return gains.astype(np.float32)
