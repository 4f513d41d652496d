"""How the gain samples its rays, and the sensor it may know (docs/sensing.md).

Two optional modes of the one gain kernel (``raycast.cl``), both off by default so that the
paper's comparison is unchanged:

* **sampling** ``"rounded"`` (the default, docs/method.md#probabilistic-ray-casting-gain): sample
  ``t = 0 .. R`` of a ray is the cell ``round(t · b_h)``, weight ``t^ν``; ``"exact"``: the cells the
  ray traverses, in order, by the simulator's exact voxel traversal (Amanatides–Woo,
  :func:`~nbv_prob_cnn.sensing.observe.trace_rays`), each weighted by its entry distance ``t^ν``
  and normalised per ray (``Σ w = 1``). Origins are cell centres, so either table depends on the
  direction only and is shared by every origin (as the rounded one always was).
* **sensor model** ``"paper"`` (the default) or ``"returns"``, :class:`GainSensor`: an unknown cell
  counts by the probability that the sensor measures it, i.e. that the ray's first return lies at
  or behind the cell, at least ``min_range`` and at most ``max_range`` away, on a surface not seen
  at grazing incidence (the same preset as the simulator). The expression is in docs/sensing.md.

:class:`RaySamples` is the table both backends read.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

#: Ray samplings, default first.
SAMPLINGS = ("rounded", "exact")
#: Sensor models of the gain, default first.
SENSOR_MODELS = ("paper", "returns")


def check_sampling(sampling: str) -> str:
    """``sampling`` if it is one of :data:`SAMPLINGS`, else a ValueError naming them."""
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling: expected one of {SAMPLINGS}, got {sampling!r}")
    return sampling


def check_sensor_model(model: str) -> str:
    """``model`` if it is one of :data:`SENSOR_MODELS`, else a ValueError naming them."""
    if model not in SENSOR_MODELS:
        raise ValueError(f"sensor_model: expected one of {SENSOR_MODELS}, got {model!r}")
    return model


@dataclass(frozen=True)
class GainSensor:
    """The sensor the ``"returns"`` gain knows. Ranges in cells.

    Attributes:
        min_range: a return closer than this is no measurement (the ray labels nothing).
        max_range: a return farther than this is no measurement.
        grazing_deg: a return whose incidence (angle between the ray and the surface normal)
            exceeds this is missing; 90 = never.
        walls: cells outside the grid return (the room's walls just outside it); False: a ray
            that leaves the grid has no return.
    """

    min_range: float = 0.0
    max_range: float = math.inf
    grazing_deg: float = 90.0
    walls: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_range) and self.min_range >= 0.0):
            raise ValueError(f"GainSensor: min_range must be finite and >= 0 cells, got {self.min_range}")
        if not self.max_range > self.min_range:
            raise ValueError(f"GainSensor: max_range ({self.max_range}) must exceed min_range ({self.min_range})")
        if not 0.0 < self.grazing_deg <= 90.0:
            raise ValueError(f"GainSensor: grazing_deg must lie in (0, 90], got {self.grazing_deg}")

    @classmethod
    def from_noise(cls, noise, resolution_m: float, walls: bool) -> GainSensor:
        """The ranges and grazing limit of a :class:`~nbv_prob_cnn.sensing.sensor_noise.SensorNoise`
        preset on a grid of ``resolution_m`` metres per cell."""
        if not resolution_m > 0:
            raise ValueError(f"resolution_m: expected > 0, got {resolution_m}")
        return cls(noise.min_range_m / resolution_m, noise.max_range_m / resolution_m, noise.grazing_deg, walls)

    @property
    def cos_grazing(self) -> float:
        """Smallest ``|cos|`` of the incidence that still returns (0 when every angle does)."""
        return 0.0 if self.grazing_deg >= 90.0 else math.cos(math.radians(self.grazing_deg))

    def reach(self, grid_shape: tuple[int, ...]) -> int:
        """Cells to march: up to ``max_range`` (no return from farther), but no farther than a ray
        can stay in a grid of ``grid_shape`` (plus its border cell)."""
        longest = math.ceil(math.sqrt(sum((n + 1) ** 2 for n in grid_shape))) + 1
        return int(max(1, min(math.floor(self.max_range), longest)))


@dataclass(frozen=True)
class RaySamples:
    """The samples of every ray, the same from every origin (a cell centre).

    Attributes:
        offsets: ``(R, K, dims)`` int16 cell offsets of sample ``k`` of ray ``h`` (rows past
            ``counts[h]`` repeat the last one).
        distance: ``(R, K)`` float64 distance of each sample (rounded: ``t``; exact: the entry
            distance of the cell, 0 for the origin's).
        counts: ``(R,)`` samples of each ray.
        weights: ``(R, K)`` float64 gain weight of each sample (0 beyond ``r_max`` and past
            ``counts``).
        total: the normaliser of ``G_r = H / total`` (rounded: ``Σ_{t<=R_max} t^ν``; exact: 1,
            the weights are normalised per ray).
        sampling: ``"rounded"`` or ``"exact"``.
    """

    offsets: np.ndarray
    distance: np.ndarray
    counts: np.ndarray
    weights: np.ndarray
    total: float
    sampling: str

    @property
    def weighted(self) -> int:
        """Columns that carry a weight (the bound of the coarse-to-fine search marches these)."""
        nonzero = np.flatnonzero(self.weights.any(axis=0))
        return int(nonzero[-1]) + 1 if nonzero.size else 1

    def first_at(self, distance: float) -> np.ndarray:
        """Per ray the first sample at ``distance`` or farther, ``(R,)`` int32."""
        at = self.distance >= distance
        first = np.where(at.any(axis=1), np.argmax(at, axis=1), self.distance.shape[1])
        return np.minimum(first, self.counts).astype(np.int32)


def ray_samples(directions: np.ndarray, r_max: int, sampling: str = "rounded", reach: int | None = None) -> RaySamples:
    """The :class:`RaySamples` of ``directions`` (``(R, dims)`` unit vectors): weights up to
    ``r_max``, samples up to ``reach`` cells (default ``r_max``; the ``"returns"`` model marches to
    the sensor's range, beyond ``r_max`` or short of it: nothing is measured past the range)."""
    full = _ray_samples(np.asarray(directions, dtype=np.float64), r_max, sampling, max(r_max, reach or r_max))
    if reach is None or reach >= r_max:
        return full
    counts = np.minimum(full.counts, np.sum(full.distance <= reach, axis=1)).astype(np.int32)
    inside = np.arange(full.distance.shape[1])[None, :] < counts[:, None]
    width = int(counts.max())
    return RaySamples(full.offsets[:, :width], full.distance[:, :width], counts,
                      np.where(inside, full.weights, 0.0)[:, :width], full.total, sampling)  # fmt: skip


def _ray_samples(directions: np.ndarray, r_max: int, sampling: str, reach: int) -> RaySamples:
    """:func:`ray_samples` with ``reach >= r_max``."""
    dims = directions.shape[1]
    if check_sampling(sampling) == "rounded":
        from nbv_prob_cnn.gain.directions import sample_offsets

        t = np.arange(reach + 1, dtype=np.float64)
        distance = np.broadcast_to(t, (directions.shape[0], reach + 1)).copy()
        weights = np.where(distance <= r_max, distance ** (dims - 1), 0.0)
        counts = np.full(directions.shape[0], reach + 1, dtype=np.int32)
        total = float(np.sum(np.arange(r_max + 1, dtype=np.float64) ** (dims - 1)))
        return RaySamples(sample_offsets(directions, reach), distance, counts, weights, total, sampling)
    offsets, distance, counts = traversal_table(directions, reach)
    inside = np.arange(distance.shape[1])[None, :] < counts[:, None]
    weights = np.where(inside & (distance <= r_max), distance ** (dims - 1), 0.0)
    sums = weights.sum(axis=1, keepdims=True)
    weights = np.where(sums > 0, weights / np.where(sums > 0, sums, 1.0), 0.0)
    return RaySamples(offsets, distance, counts, weights, 1.0, sampling)


def traversal_table(directions: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact traversal of each ray from a cell centre, with the simulator's traversal
    (:func:`~nbv_prob_cnn.sensing.observe.trace_rays`): the cells it enters within ``limit``,
    as ``(offsets (R, K, dims) int16, entry distance (R, K), counts (R,) int32)``, read-only. The
    last few tables are kept (a view's surface estimate reads its rays' table twice: 0.12 s for
    32 x 32 rays of range 128)."""
    rays = np.ascontiguousarray(directions, dtype=np.float64)
    return _traversal_table(rays.tobytes(), rays.shape[1], float(limit))


@functools.lru_cache(maxsize=4)
def _traversal_table(key: bytes, dims: int, limit: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`traversal_table` of the directions whose float64 bytes are ``key``."""
    from nbv_prob_cnn.sensing.observe import trace_rays

    directions = np.frombuffer(key, dtype=np.float64).reshape(-1, dims)
    half = int(math.ceil(limit)) + 2
    shape = (2 * half + 1,) * dims
    trace = trace_rays(shape, np.full(dims, float(half)), directions, float(limit), None)
    order = np.lexsort((trace.t_enter, trace.ray))  # per ray in traversal order
    ray, cell, enter = trace.ray[order], trace.cell[order], trace.t_enter[order]
    counts = np.bincount(ray, minlength=directions.shape[0]).astype(np.int32)
    width = int(counts.max())
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    column = np.arange(ray.size) - start[ray]
    index = np.stack(np.unravel_index(cell, shape), axis=1) - half
    offsets = np.zeros((directions.shape[0], width, dims), dtype=np.int16)
    distance = np.zeros((directions.shape[0], width))
    offsets[ray, column] = index
    distance[ray, column] = enter
    last = counts - 1  # pad with the last cell (never read: each ray marches its own count)
    pad = np.arange(width)[None, :] >= counts[:, None]
    rows = np.nonzero(pad)[0]
    offsets[pad] = offsets[rows, last[rows]]
    distance[pad] = distance[rows, last[rows]]
    for table in (offsets, distance, counts):
        table.setflags(write=False)
    return offsets, distance, counts


def occupancy_normals(state: np.ndarray, prob: np.ndarray | None) -> np.ndarray:
    """Unit surface normal of every cell, ``(dims, *shape)`` float32: the negative central-difference
    gradient of the occupancy (known occupied 1, empty 0, unknown its probability; 0 without
    ``prob``), the simulator's normal (:func:`~nbv_prob_cnn.sensing.observe.surface_cosine`);
    zero where the gradient vanishes (no grazing test there)."""
    occupancy = np.where(state == 1, 1.0, 0.0)
    if prob is not None:
        occupancy = np.where(state == -1, np.asarray(prob, dtype=np.float64), occupancy)
    normal = np.zeros((state.ndim, *state.shape))
    for axis in range(state.ndim):
        n = state.shape[axis]
        up = np.take(occupancy, np.minimum(np.arange(n) + 1, n - 1), axis=axis)
        down = np.take(occupancy, np.maximum(np.arange(n) - 1, 0), axis=axis)
        normal[axis] = down - up
    norm = np.sqrt(np.sum(normal**2, axis=0))
    return np.where(norm > 1e-9, normal / np.maximum(norm, 1e-12), 0.0).astype(np.float32)


def border_normal(cells: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Normal of the grid's border (the walls) at cells just outside the grid, ``(..., dims)``:
    the unit sum of the faces' normals the cell lies beyond (a corner cell: several)."""
    cells = np.asarray(cells)
    outside = (cells < 0).astype(np.float64) - (cells >= np.array(shape)).astype(np.float64)
    norm = np.linalg.norm(outside, axis=-1, keepdims=True)
    return np.where(norm > 0, outside / np.maximum(norm, 1e-12), 0.0)
