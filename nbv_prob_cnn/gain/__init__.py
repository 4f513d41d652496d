"""Probabilistic ray-casting gain (docs/method.md#probabilistic-ray-casting-gain) and view evaluation
(docs/method.md#candidate-views-and-view-gain).

Public API:
    * :func:`ray_directions` — the ``H_r`` unit vectors.
    * :func:`ray_gains` — ``G_r(v, h)`` for every origin and ray, on the ``"opencl"`` kernel or
      the ``"numpy"`` reference.
    * :func:`origin_view_gains` — ``G_W(v, W)`` for every origin and candidate view (the
      planners' path; on OpenCL one fused kernel that never stores per-ray gains).
    * :func:`view_gains` — ``G_W(v, W)`` from given ray gains, one (origins × rays) @ (rays × views)
      product (also the numpy reference of :func:`origin_view_gains`).

Each gain function takes two optional modes (docs/sensing.md, :mod:`nbv_prob_cnn.gain.sampling`):
``sensor`` (a :class:`~nbv_prob_cnn.gain.sampling.GainSensor`: the ``"returns"`` sensor model; None,
the default: the paper's gain) and ``sampling`` (``"rounded"``, the default, or ``"exact"``
voxel traversal), both with the paper's variant only.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.basics.camera import in_frustum
from nbv_prob_cnn.basics.grid import check_probability, check_state, lattice_index
from nbv_prob_cnn.basics.modes import BACKEND_NAMES
from nbv_prob_cnn.gain.best_view import BestOriginView
from nbv_prob_cnn.gain.directions import check_directions, distance_weights, ray_directions, sample_offsets
from nbv_prob_cnn.gain.reference import (
    ig_gains_reference,
    original_ray_terms,
    original_view_gains_reference,
    ray_gains_reference,
    sampled_ray_gains,
)
from nbv_prob_cnn.gain.sampling import GainSensor, check_sampling, occupancy_normals, ray_samples
from nbv_prob_cnn.gain.variant import GAIN_VARIANTS, check_variant, sample_count, sample_weights

#: Ray-casting backends (defined once, in :mod:`nbv_prob_cnn.basics.modes`).
BACKENDS = BACKEND_NAMES

__all__ = [
    "BACKENDS", "ray_directions", "ray_gains", "origin_view_gains", "view_gains", "view_membership",
    "empty_origins", "best_origin_view", "BestOriginView", "GAIN_VARIANTS", "GainSensor",
]  # fmt: skip


def empty_origins(state: np.ndarray, stride: int = 1) -> np.ndarray:
    """Empty cells of ``state`` in ``np.argwhere`` order; with ``stride > 1`` only cells whose
    every coordinate is a multiple of ``stride`` (3DT uses 2: one cell in 8)."""
    empty = state == 0
    if stride > 1:
        sub = np.zeros_like(empty)
        keep = lattice_index(state.ndim, stride)
        sub[keep] = empty[keep]
        empty = sub
    return np.argwhere(empty)


def _check_origins(origins: np.ndarray | None, state: np.ndarray) -> np.ndarray:
    if origins is None:
        return empty_origins(state)
    arr = np.asarray(origins)
    if arr.ndim != 2 or arr.shape[1] != state.ndim:
        raise ValueError(f"origins: expected an (N, {state.ndim}) integer array, got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"origins: expected integer cell indices, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    if arr.size and (np.any(arr < 0) or np.any(arr >= np.array(state.shape))):
        raise ValueError(f"origins: cell indices outside the grid of shape {state.shape}")
    return arr


def ray_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    origins: np.ndarray | None = None,
    backend: str = "auto",
    *,
    mode: str = "prob",
    eps: float = 0.0,
    min_range: float = 0.0,
    variant: str = "paper",
    free_hits: bool = False,
    sensor: GainSensor | None = None,
    sampling: str = "rounded",
) -> np.ndarray:
    """Normalised ray gain ``G_r(v, h) = H / (H + M)`` of docs/method.md#probabilistic-ray-casting-gain.

    Args:
        state: ternary ``int8`` grid ``C`` (2D or 3D).
        prob: probabilistic map ``P`` (float32, same shape, in [0, 1]); only read in unknown
            cells. Ignored (may be None) with ``mode="ig"``.
        directions: ``(R, dims)`` unit vectors, e.g. from :func:`ray_directions`.
        r_max: maximum range ``N`` in cells; samples ``t = 0..r_max``.
        origins: ``(N, dims)`` integer cell indices; default: every empty cell
            (``np.argwhere`` order).
        backend: ``"opencl"``, ``"numpy"`` (reference) or ``"auto"`` (OpenCL if a device works).
        mode: ``"prob"`` (equations (2)–(6)) or ``"ig"`` (non-probabilistic information gain:
            the first non-empty sample, weighted ``t^nu / sum t^nu``, if unknown and
            ``t >= min_range``).
        eps: OpenCL only: stop a ray once ``Pr(r_t) <= eps``. ``0`` is exact (a ray stops only
            when ``Pr`` is exactly 0: occupied cell or grid border). With ``eps > 0`` each
            ``G_r`` is under-estimated by less than ``eps`` (the remaining terms sum to at
            most ``Pr * sum_t t^nu``).
        min_range: ``mode="ig"`` only, minimum sensor range in cells.
        variant: ``"paper"`` (docs/method.md#probabilistic-ray-casting-gain) or ``"original"`` (the authors'
        host choices: range,
            weights, normalisation, ``ig``; :mod:`nbv_prob_cnn.gain.variant`).
        free_hits: ``variant="original"``, ``mode="prob"`` only: an unknown sample counts
            ``(1 - p_t) Pr(r_t)`` (the original's CNN and oracle maps).
        sensor: the ``"returns"`` sensor model (:class:`~nbv_prob_cnn.gain.sampling.GainSensor`,
            docs/sensing.md): an unknown cell counts by the probability that the sensor measures
            it; with ``mode="ig"`` only its minimum range replaces ``min_range``. None: the paper's.
        sampling: ``"rounded"`` (docs/method.md) or ``"exact"`` voxel traversal of the rays.

    Returns:
        ``(N, R)`` float32 in [0, 1].

    Raises:
        ValueError: bad grid, probability map, directions, origins, range, mode or backend.
    """
    state, prob, directions, origins, backend = _check_gain_inputs(
        state, prob, directions, r_max, origins, backend, mode, eps
    )
    kernel_mode = _kernel_mode(mode, variant, free_hits)
    options = _march_options(state, prob, directions, r_max, mode, min_range, variant, free_hits, sensor, sampling)
    if options is not None:
        min_range = options.min_range
        if backend == "numpy":
            return _reference_sampled(state, prob, directions, origins, mode, options)
        from nbv_prob_cnn.gain.opencl import encode_grid, get_ray_caster

        code = encode_grid(state, prob if mode == "prob" else None)
        return get_ray_caster().run(code, origins, options.samples.offsets, options.samples.total, kernel_mode, eps,
                                    min_range, variant, options)  # fmt: skip
    if backend == "numpy":
        return _reference_ray_gains(state, prob, directions, r_max, origins, mode, min_range, variant, free_hits)
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    code, offsets, total = _kernel_inputs(state, prob, directions, r_max, mode, variant)
    return get_ray_caster().run(code, origins, offsets, total, kernel_mode, eps, min_range, variant)


def origin_view_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    membership: np.ndarray,
    origins: np.ndarray | None = None,
    backend: str = "auto",
    *,
    mode: str = "prob",
    eps: float = 0.0,
    min_range: float = 0.0,
    variant: str = "paper",
    free_hits: bool = False,
    sensor: GainSensor | None = None,
    sampling: str = "rounded",
) -> np.ndarray:
    """``G_W(v, W)`` (equation (7)) for every origin ``v`` and candidate view ``W``.

    The same gain as ``ray_gains(...) @ membership``; the OpenCL backend sums the rays of each
    view in local memory and never stores the ``(N, R)`` ray gains.

    Args:
        membership: ``(R, V)`` 0/1 matrix, ray ``h`` inside view ``W`` (:func:`view_membership`).
        Others: as :func:`ray_gains`.

    Returns:
        ``(N, V)`` float32.

    Raises:
        ValueError: bad inputs (as :func:`ray_gains`) or a membership matrix of the wrong shape.
    """
    state, prob, directions, origins, backend = _check_gain_inputs(
        state, prob, directions, r_max, origins, backend, mode, eps
    )
    member = _check_membership(membership, directions)
    kernel_mode = _kernel_mode(mode, variant, free_hits)
    options = _march_options(state, prob, directions, r_max, mode, min_range, variant, free_hits, sensor, sampling)
    if options is not None:
        if backend == "numpy":
            return _reference_sampled(state, prob, directions, origins, mode, options) @ member.astype(np.float32)
        from nbv_prob_cnn.gain.opencl import encode_grid, get_ray_caster

        code = encode_grid(state, prob if mode == "prob" else None)
        return get_ray_caster().run_views(code, origins, options.samples.offsets, member, options.samples.total,
                                          kernel_mode, eps, options.min_range, variant=variant,
                                          options=options)  # fmt: skip
    if backend == "numpy":
        return _reference_view_gains(state, prob, directions, r_max, member, origins, mode, min_range, variant,
                                     free_hits)  # fmt: skip
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    code, offsets, total = _kernel_inputs(state, prob, directions, r_max, mode, variant)
    return get_ray_caster().run_views(code, origins, offsets, member, total, kernel_mode, eps, min_range,
                                      variant=variant)  # fmt: skip


def best_origin_view(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    membership: np.ndarray,
    origins: np.ndarray | None = None,
    backend: str = "auto",
    *,
    mode: str = "prob",
    eps: float = 0.0,
    min_range: float = 0.0,
    variant: str = "paper",
    free_hits: bool = False,
    sensor: GainSensor | None = None,
    sampling: str = "rounded",
    block_size: int | None = None,
    prune_views: bool = True,
) -> BestOriginView:
    """The argmax of :func:`origin_view_gains` (the first of equal maxima, origin-major):
    ``(origin position in origins, view, gain)``; position -1 when there are no origins.
    The result unpacks as that 3-tuple and also carries the origin's ``cell``;
    ``result.pose(geometry)`` gives the camera position in metres and its quaternion
    (:class:`~nbv_prob_cnn.gain.best_view.BestOriginView`).

    On OpenCL a coarse-to-fine search that is exact for the argmax (bounds per 2-cell block of
    origins prune the origins that cannot reach the best gain; see
    :meth:`~nbv_prob_cnn.gain.opencl.OpenCLRayCaster.best_view`); the numpy reference evaluates
    every origin. ``block_size``: origins per axis of a bounded block (default
    :data:`~nbv_prob_cnn.gain.opencl.BOUND_BLOCK`; origins on a stride ``s`` want ``2 s``).
    ``prune_views``: evaluate only the views whose block bound reaches the best gain found so far
    (False: every view of every evaluated origin; the same result, for comparison).
    """
    state, prob, directions, origins, backend = _check_gain_inputs(
        state, prob, directions, r_max, origins, backend, mode, eps
    )
    member = _check_membership(membership, directions)
    kernel_mode = _kernel_mode(mode, variant, free_hits)
    if origins.shape[0] == 0:
        return BestOriginView(-1, 0, 0.0)
    if backend == "numpy":
        gains = origin_view_gains(state, prob, directions, r_max, member, origins, "numpy", mode=mode,
                                  min_range=min_range, variant=variant, free_hits=free_hits, sensor=sensor,
                                  sampling=sampling)  # fmt: skip
        flat = int(np.argmax(gains))
        index = flat // gains.shape[1]
        return BestOriginView(index, flat % gains.shape[1], float(gains.flat[flat]), origins[index])
    from nbv_prob_cnn.gain.opencl import BOUND_BLOCK, get_ray_caster

    if block_size is not None and (not isinstance(block_size, (int, np.integer)) or block_size < 1):
        raise ValueError(f"block_size: expected a positive integer, got {block_size!r}")
    options = _march_options(state, prob, directions, r_max, mode, min_range, variant, free_hits, sensor, sampling)
    if options is None:
        code, offsets, total = _kernel_inputs(state, prob, directions, r_max, mode, variant)
    else:
        from nbv_prob_cnn.gain.opencl import encode_grid

        code = encode_grid(state, prob if mode == "prob" else None)
        offsets, total, min_range = options.samples.offsets, options.samples.total, options.min_range
    origin, view, gain, _ = get_ray_caster().best_view(
        code, origins, offsets, member, total, kernel_mode, eps, min_range, block_size=block_size or BOUND_BLOCK,
        prune_views=prune_views, variant=variant, options=options,
    )  # fmt: skip
    return BestOriginView(origin, view, gain, origins[origin] if origin >= 0 else None)


def _reference_ray_gains(state, prob, directions, r_max, origins, mode, min_range, variant="paper",
                         free_hits=False) -> np.ndarray:  # fmt: skip
    """``(N, R)`` ray gains from the numpy reference of ``mode`` and ``variant``."""
    if variant == "original":
        hits, totals = original_ray_terms(state, prob, directions, r_max, origins, mode, free_hits, min_range)
        return np.where(totals > 0, hits / np.where(totals > 0, totals, 1.0), 0.0).astype(np.float32)
    if mode == "ig":
        return ig_gains_reference(state, directions, r_max, origins, min_range)
    return ray_gains_reference(state, prob, directions, r_max, origins)


def _reference_view_gains(state, prob, directions, r_max, member, origins, mode, min_range, variant,
                          free_hits) -> np.ndarray:  # fmt: skip
    """``(N, V)`` view gains from the numpy reference: equation (7), or the original's ratio."""
    if variant == "original":
        hits, totals = original_ray_terms(state, prob, directions, r_max, origins, mode, free_hits, min_range)
        return original_view_gains_reference(hits, totals, member)
    rays = _reference_ray_gains(state, prob, directions, r_max, origins, mode, min_range)
    return rays @ member.astype(np.float32)


def _march_options(state, prob, directions, r_max, mode, min_range, variant, free_hits, sensor, sampling):
    """The :class:`~nbv_prob_cnn.gain.opencl.MarchOptions` of ``sensor`` and ``sampling``, or None
    for the paper's gain on rounded samples (the default path, unchanged)."""
    from nbv_prob_cnn.gain.opencl import MarchOptions

    check_sampling(sampling)
    if sensor is not None and not isinstance(sensor, GainSensor):
        raise ValueError(f"sensor: expected a GainSensor or None, got {type(sensor).__name__}")
    if sensor is None and sampling == "rounded":
        return None
    if variant != "paper" or free_hits:
        raise ValueError(f"sensor/sampling: only with the paper's gain variant, got {variant!r}")
    if mode == "ig" and sensor is not None:  # ig: the first unknown cell is the return
        min_range, sensor = sensor.min_range, None
    if sensor is None:
        return MarchOptions(ray_samples(directions, r_max, sampling), float(min_range))
    samples = ray_samples(directions, r_max, sampling, sensor.reach(state.shape))
    return MarchOptions(samples, sensor.min_range, sensor, directions, occupancy_normals(state, prob))


def _reference_sampled(state, prob, directions, origins, mode, options) -> np.ndarray:
    """``(N, R)`` ray gains of the numpy reference of ``options`` (:func:`sampled_ray_gains`)."""
    return sampled_ray_gains(state, prob, options.samples, origins, mode, options.min_range, options.sensor,
                             directions)  # fmt: skip


def _kernel_mode(mode: str, variant: str, free_hits: bool) -> str:
    """The kernel's mode (``prob``, ``ig`` or ``prob_free``) after checking ``variant``/``free_hits``."""
    check_variant(variant)
    if not free_hits:
        return mode
    if variant != "original" or mode != "prob":
        raise ValueError(f"free_hits: only with variant='original' and mode='prob', got {variant!r}, {mode!r}")
    return "prob_free"


def _kernel_inputs(state, prob, directions, r_max, mode, variant="paper") -> tuple[np.ndarray, np.ndarray, float]:
    """What every OpenCL gain kernel reads: the encoded grid, the sample offsets of the rays and
    the weight normaliser (``sum t^nu``; for the original variant its range and weights)."""
    from nbv_prob_cnn.gain.opencl import encode_grid

    code = encode_grid(state, prob if mode == "prob" else None)
    if variant == "paper":
        return code, sample_offsets(directions, r_max), float(distance_weights(r_max, state.ndim).sum())
    n_samples = sample_count(variant, r_max)
    total = float(sample_weights(variant, n_samples, state.ndim).sum())
    return code, sample_offsets(directions, n_samples - 1), total


def _check_membership(membership: np.ndarray, directions: np.ndarray) -> np.ndarray:
    member = np.asarray(membership)
    if member.ndim != 2 or member.shape[0] != directions.shape[0] or not np.all((member == 0) | (member == 1)):
        raise ValueError(f"membership: expected a ({directions.shape[0]}, V) 0/1 matrix, got shape {member.shape}")
    return member


def _check_gain_inputs(state, prob, directions, r_max, origins, backend, mode, eps):
    """Validate the shared arguments of the gain functions; resolve ``backend="auto"``."""
    state = check_state(state)
    if mode not in ("prob", "ig"):
        raise ValueError(f"mode: expected 'prob' or 'ig', got {mode!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if not isinstance(r_max, (int, np.integer)) or not 1 <= r_max <= 4096:
        raise ValueError(f"r_max: expected an integer range in cells in [1, 4096], got {r_max!r}")
    if not (np.isfinite(eps) and 0.0 <= eps < 1.0):
        raise ValueError(f"eps: expected a tolerance in [0, 1), got {eps!r}")
    if mode == "prob":
        if prob is None:
            raise ValueError("prob: a probability map is required for mode='prob'")
        prob = check_probability(prob, state.shape)
    directions = check_directions(directions, state.ndim)
    origins = _check_origins(origins, state)
    if backend == "auto":
        from nbv_prob_cnn.basics.cl_device import opencl_available

        backend = "opencl" if opencl_available() else "numpy"
    return state, prob, directions, origins, backend


def view_membership(
    directions: np.ndarray, orientations: np.ndarray, hfov_deg: float, vfov_deg: float | None = None
) -> np.ndarray:
    """``(R, V)`` float32 0/1 matrix: ray ``h`` lies in the frustum of view ``W``."""
    return in_frustum(directions, orientations, hfov_deg, vfov_deg).astype(np.float32)


def view_gains(
    ray_gains: np.ndarray,
    directions: np.ndarray,
    orientations: np.ndarray,
    hfov_deg: float,
    vfov_deg: float | None = None,
) -> np.ndarray:
    """``G_W(v, W) = sum of G_r(v, h) over the rays h inside the view W`` (equation (7)).

    Args:
        ray_gains: ``(N, R)`` from :func:`ray_gains`.
        directions: the ``(R, dims)`` directions used for ``ray_gains``.
        orientations: ``(V,)`` yaws (2D) or ``(V, 4)`` quaternions (3D).

    Returns:
        ``(N, V)`` float32.
    """
    gains = np.asarray(ray_gains)
    dims = np.asarray(directions).shape[-1] if np.ndim(directions) == 2 else 0
    directions = check_directions(directions, dims if dims in (2, 3) else 3)
    if gains.ndim != 2 or gains.shape[1] != directions.shape[0]:
        raise ValueError(f"ray_gains: expected shape (N, {directions.shape[0]}), got {gains.shape}")
    if not np.all(np.isfinite(gains)):
        raise ValueError("ray_gains: contains NaN or infinite values")
    membership = view_membership(directions, orientations, hfov_deg, vfov_deg)
    return gains.astype(np.float32, copy=False) @ membership
