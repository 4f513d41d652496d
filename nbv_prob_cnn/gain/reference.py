"""Plain numpy reference of the ray gain (docs/method.md#probabilistic-ray-casting-gain): the literal
equations, no early stop; and
of the original variant (:func:`original_ray_terms`, the authors' host choices); and of the optional
exact-traversal sampling and ``"returns"`` sensor model (:func:`sampled_ray_gains`, docs/sensing.md).

It is the readable implementation the OpenCL kernel is tested against (vectorized over
origins and rays, a Python loop over the samples ``t``).
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.gain.directions import distance_weights, sample_offsets
from nbv_prob_cnn.gain.march import MarchOptions
from nbv_prob_cnn.gain.sampling import GainSensor, RaySamples, border_normal, occupancy_normals
from nbv_prob_cnn.gain.settings import GainSettings
from nbv_prob_cnn.gain.variant import ORIGINAL_IG_MIN_RANGE, ORIGINAL_NEAR_HIT, sample_count, sample_weights

_CHUNK = 2048  # origins per block, bounds the (chunk, R, dims) temporaries


def _sample_cells(shape: tuple[int, ...], origins: np.ndarray, offset_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whether each sample cell ``origins[:, None] + offset_t[None]`` lies inside the grid, and its
    flat (C-order) index, clamped into the grid, each ``(N, R)``. Axis by axis on ``(N, R)``
    arrays: one flat gather per grid instead of an ``(N, R, dims)`` cell array, its clip against
    a shape array (numpy's slow path) and a tuple index (2.5x faster, the same cells)."""
    offset = offset_t.astype(np.int64)
    flat = np.zeros((origins.shape[0], offset.shape[0]), dtype=np.int64)
    inside = np.ones(flat.shape, dtype=bool)
    for axis, size in enumerate(shape):
        coord = origins[:, axis, None].astype(np.int64) + offset[None, :, axis]
        inside &= (coord >= 0) & (coord < size)
        flat *= size
        flat += np.minimum(np.maximum(coord, 0), size - 1)
    return inside, flat


def _sample(state: np.ndarray, values: np.ndarray, outside: float, origins: np.ndarray, offset_t: np.ndarray):
    """``values`` at sample cells ``origins[:, None] + offset_t[None]`` (``outside`` where a
    cell is outside the grid), plus the state there (1 = occupied outside)."""
    inside, flat = _sample_cells(state.shape, origins, offset_t)
    return np.where(inside, np.take(values, flat), outside), np.where(inside, np.take(state, flat), 1)


def ray_terms(
    state: np.ndarray,
    prob: np.ndarray,
    directions: np.ndarray,
    r_max: int,
    origins: np.ndarray,
    surface: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """``H(v, h)`` and ``M(v, h)`` of equations (4)–(5), each ``(N, R)`` float64.

    ``p`` is read from ``prob`` in unknown cells only; known cells use 0 (empty) and 1
    (occupied). Cells outside the grid count as known occupied (``p = 1``, ``o = 1``).
    ``surface``: the surface blend ``beta`` (docs/method.md#surface-gain): an unknown sample adds
    ``w_t Pr(r_t) ((1 - beta) + beta p_t)`` to ``H`` (``M`` is the paper's).
    """
    weights = distance_weights(r_max, state.ndim)
    offsets = sample_offsets(directions, r_max)
    hit = np.zeros((origins.shape[0], directions.shape[0]))
    miss = np.zeros_like(hit)
    for start in range(0, origins.shape[0], _CHUNK):
        block = slice(start, start + _CHUNK)
        visible = np.ones_like(hit[block])  # Pr(r_t) = prod_{i<t} (1 - p(v_i))
        for t in range(r_max + 1):
            p_unknown, value = _sample(state, prob, 1.0, origins[block], offsets[:, t])
            unknown = value == -1
            p = np.where(unknown, p_unknown, value == 1)
            hit[block] += unknown * visible * weights[t] * ((1.0 - surface) + surface * p)
            miss[block] += np.where(unknown, 1.0 - visible, 1.0) * weights[t]
            visible = visible * (1.0 - p)
    return hit, miss


def ray_gains_reference(
    state: np.ndarray,
    prob: np.ndarray,
    directions: np.ndarray,
    r_max: int,
    origins: np.ndarray,
    surface: float = 0.0,
) -> np.ndarray:
    """``G_r = H / (H + M)`` (equation (6)), ``(N, R)`` float32. ``surface``: ``H`` as :func:`ray_terms`,
    over the paper's ``H + M``, which is the sum of the weights."""
    hit, miss = ray_terms(state, prob, directions, r_max, origins, surface)
    if surface:
        return (hit / distance_weights(r_max, state.ndim).sum()).astype(np.float32)
    return (hit / (hit + miss)).astype(np.float32)


def ig_gains_reference(
    state: np.ndarray, directions: np.ndarray, r_max: int, origins: np.ndarray, min_range: float = 0.0
) -> np.ndarray:
    """Non-probabilistic information gain: each ray stops at its first non-empty sample and
    scores ``t^nu / sum_t t^nu`` if that sample is unknown with ``min_range <= t <= r_max``."""
    weights = distance_weights(r_max, state.ndim)
    offsets = sample_offsets(directions, r_max)
    gains = np.zeros((origins.shape[0], directions.shape[0]))
    for start in range(0, origins.shape[0], _CHUNK):
        block = slice(start, start + _CHUNK)
        running = np.ones(gains[block].shape, dtype=bool)
        for t in range(r_max + 1):
            _, value = _sample(state, state, 1, origins[block], offsets[:, t])
            stops = running & (value != 0)
            gains[block] += np.where(stops & (value == -1) & (t >= min_range), weights[t], 0.0)
            running &= ~stops
    return (gains / weights.sum()).astype(np.float32)


def original_ray_terms(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    origins: np.ndarray,
    mode: str = "prob",
    free_hits: bool = False,
    min_range: float = ORIGINAL_IG_MIN_RANGE,
) -> tuple[np.ndarray, np.ndarray]:
    """Per ray the hits and hits + miss of the original variant (:mod:`~nbv_prob_cnn.gain.variant`),
    each ``(N, R)`` float64, from its own description of the authors' host and kernel: samples
    ``t = 0 .. N - 1`` of the shorter range, weights ``min((t / f)^nu, 1)``, cells outside the grid
    empty (no hit, no occlusion: the ray can never come back), known occupied cells occluding.

    ``mode="prob"``: an unknown sample adds ``w_t (1 - q_t) Pr(r_t)`` to the hits, ``q_t = p_t``
    with ``free_hits`` (CNN or oracle map), else 0; every sample adds the rest of ``w_t`` to the
    misses (hits + miss = sum of the weights). ``mode="ig"``: the first sample inside the grid
    that is not known empty ends the ray: unknown, it scores ``w_t`` (``0.01`` if ``t <
    min_range``); occupied, nothing; the misses are the weights before it plus ``1 - hits``.
    """
    n = sample_count("original", r_max)
    weights = sample_weights("original", n, state.ndim)
    offsets = sample_offsets(directions, n - 1)
    hits = np.zeros((origins.shape[0], directions.shape[0]))
    totals = np.full_like(hits, weights.sum())
    values = prob if prob is not None else np.zeros(state.shape, dtype=np.float32)
    for start in range(0, origins.shape[0], _CHUNK):
        block = slice(start, start + _CHUNK)
        visible = np.ones_like(hits[block])
        running = np.ones(hits[block].shape, dtype=bool)
        before = 0.0  # weights of the samples before t
        for t in range(n):
            inside, flat = _sample_cells(state.shape, origins[block], offsets[:, t])
            p_unknown = np.where(inside, np.take(values, flat), 0.0)
            value = np.where(inside, np.take(state, flat), 1)
            unknown = inside & (value == -1)
            occupied = inside & (value == 1)
            if mode == "ig":
                stops = running & (unknown | occupied)
                score = weights[t] if t >= min_range else ORIGINAL_NEAR_HIT
                hits[block] += np.where(stops & unknown, score, 0.0)
                totals[block] = np.where(stops, before + 1.0, totals[block])
                running &= ~stops
            else:
                free = 1.0 - p_unknown if free_hits else 1.0
                hits[block] += np.where(unknown, weights[t] * free * visible, 0.0)
                visible = np.where(unknown, visible * (1.0 - p_unknown), np.where(occupied, 0.0, visible))
            before += weights[t]
    return hits, totals


def original_view_gains_reference(hits: np.ndarray, totals: np.ndarray, membership: np.ndarray) -> np.ndarray:
    """The original view gain: per view the sum of its rays' hits over the sum of their hits +
    miss (0 for a view without rays), ``(N, V)`` float32."""
    member = np.asarray(membership, dtype=np.float64)
    num, den = hits @ member, totals @ member
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0).astype(np.float32)


def sampled_ray_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    samples: RaySamples,
    origins: np.ndarray,
    mode: str = "prob",
    min_range: float = 0.0,
    sensor: GainSensor | None = None,
    directions: np.ndarray | None = None,
    surface: float = 0.0,
) -> np.ndarray:
    """``G_r`` of the paper's gain on any :class:`~nbv_prob_cnn.gain.sampling.RaySamples` table
    (rounded or exact traversal), and of the ``"returns"`` sensor model (``sensor`` given), from
    the literal sums, ``(N, R)`` float32.

    Paper (``sensor`` None): ``H = Σ_k u_k w_k Pr_k``, ``Pr_k = Π_{i<k} (1 - p_i)``, cells outside
    the grid occupied; ``ig``: the weight of the first non-empty sample if it is unknown and at
    least ``min_range`` away. ``"returns"`` (``mode="prob"``): ``H = Σ_k u_k w_k Σ_{j>=k} q_j``
    with ``q_j = Pr_j p_j g_j`` for samples ``j`` between the sensor's minimum and maximum range
    (else 0): the probability that the first return is at or behind sample ``k`` and is measured;
    ``g_j = 0`` at grazing incidence (the normal of :func:`occupancy_normals`, outside the grid the
    border's), cells outside the grid occupied with ``sensor.walls``, else empty (no return).
    ``G_r = H / samples.total``. ``surface`` (``beta``, docs/method.md#surface-gain): without a sensor
    an unknown sample counts ``(1 - beta) + beta p_k`` times its term; with one ``H`` becomes
    ``(1 - beta) H + beta Σ_k u_k w_k q_k`` (the return measured at an unknown sample).
    """
    n_rays, width = samples.distance.shape
    valid = np.arange(width)[None, :] < samples.counts[:, None]  # (R, K)
    occupancy = np.where(state == 1, 1.0, 0.0)
    if prob is not None:
        occupancy = np.where(state == -1, prob, occupancy)
    if sensor is not None:
        normals = occupancy_normals(state, prob)
        b = np.asarray(directions, dtype=np.float32)  # (R, dims)
        returns_range = valid & (samples.distance >= sensor.min_range) & (samples.distance <= sensor.max_range)
    gains = np.zeros((origins.shape[0], n_rays))
    chunk = 64
    for start in range(0, origins.shape[0], chunk):
        o = origins[start : start + chunk]
        cells = o[:, None, None, :] + samples.offsets[None].astype(np.int64)  # (n, R, K, dims)
        inside = np.all((cells >= 0) & (cells < np.array(state.shape)), axis=3)
        index = tuple(np.clip(cells, 0, np.array(state.shape) - 1).transpose(3, 0, 1, 2))
        value = np.where(inside, state[index], 1)
        unknown = inside & (value == -1) & valid[None]
        outside_p = 1.0 if sensor is None or sensor.walls else 0.0
        p = np.where(inside, occupancy[index], outside_p) * valid[None]
        if mode == "ig":
            stops = (value != 0) & valid[None]
            first = np.argmax(stops, axis=2)
            has = np.take_along_axis(stops, first[..., None], axis=2)[..., 0]
            at = np.take_along_axis(unknown, first[..., None], axis=2)[..., 0]
            far = samples.distance[np.arange(n_rays)[None, :], first] >= min_range
            w = samples.weights[np.arange(n_rays)[None, :], first]
            gains[start : start + chunk] = np.where(has & at & far, w, 0.0)
            continue
        visible = np.concatenate([np.ones(p.shape[:2] + (1,)), np.cumprod(1.0 - p, axis=2)[..., :-1]], axis=2)
        if sensor is None:
            measured = visible * ((1.0 - surface) + surface * p)
        else:
            normal = np.where(
                inside[..., None],
                np.moveaxis(normals, 0, -1)[index],
                border_normal(cells, state.shape),
            ).astype(np.float32)  # (n, R, K, dims)
            dot = np.abs(np.sum(normal * b[None, :, None, :], axis=3, dtype=np.float32))
            facing = (np.sum(normal * normal, axis=3) == 0) | (dot >= np.float32(sensor.cos_grazing))
            q = visible * p * facing * returns_range[None]
            measured = (1.0 - surface) * np.cumsum(q[..., ::-1], axis=2)[..., ::-1] + surface * q  # Σ_{j >= k} q_j
        gains[start : start + chunk] = np.sum(unknown * samples.weights[None] * measured, axis=2)
    return (gains / samples.total).astype(np.float32)


def reference_ray_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    origins: np.ndarray,
    settings: GainSettings,
    options: MarchOptions | None = None,
) -> np.ndarray:
    """``(N, R)`` float32 ray gains of ``settings`` from the reference of its variant, mode and
    optional modes (``options``, :func:`~nbv_prob_cnn.gain.march.march_options`)."""
    if options is not None:
        return sampled_ray_gains(state, prob, options.samples, origins, settings.mode, options.min_range,
                                 options.sensor, directions, settings.surface)  # fmt: skip
    if settings.variant == "original":
        hits, totals = _original_terms(state, prob, directions, r_max, origins, settings)
        return np.where(totals > 0, hits / np.where(totals > 0, totals, 1.0), 0.0).astype(np.float32)
    if settings.mode == "ig":
        return ig_gains_reference(state, directions, r_max, origins, settings.min_range)
    if prob is None:
        raise ValueError("prob: a probability map is required for mode='prob'")
    return ray_gains_reference(state, prob, directions, r_max, origins, settings.surface)


def reference_view_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    membership: np.ndarray,
    origins: np.ndarray,
    settings: GainSettings,
    options: MarchOptions | None = None,
) -> np.ndarray:
    """``(N, V)`` float32 view gains of ``settings``: equation (7) over the reference's ray gains,
    or the original variant's ratio (:func:`original_view_gains_reference`)."""
    if options is None and settings.variant == "original":
        hits, totals = _original_terms(state, prob, directions, r_max, origins, settings)
        return original_view_gains_reference(hits, totals, membership)
    rays = reference_ray_gains(state, prob, directions, r_max, origins, settings, options)
    return rays @ membership.astype(np.float32)


def _original_terms(state, prob, directions, r_max, origins, settings: GainSettings):
    """:func:`original_ray_terms` of ``settings``."""
    return original_ray_terms(state, prob, directions, r_max, origins, settings.mode, settings.free_hits,
                              settings.min_range)  # fmt: skip
