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

Each gain function takes one :class:`~nbv_prob_cnn.gain.settings.GainSettings` (``settings=``; the
default :data:`PAPER_GAIN` is the paper's gain): the mode (``"prob"`` or ``"ig"``), the kernel's
early-stop tolerance, the minimum range, the gain variant, and two optional modes
(docs/sensing.md, :mod:`nbv_prob_cnn.gain.sampling`): ``sensor`` (a
:class:`~nbv_prob_cnn.gain.sampling.GainSensor`: the ``"returns"`` sensor model) and ``sampling``
(``"rounded"`` or ``"exact"`` voxel traversal), both with the paper's variant only.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.basics.camera import in_frustum
from nbv_prob_cnn.basics.grid import check_probability, check_state, lattice_index
from nbv_prob_cnn.basics.modes import BACKEND_NAMES
from nbv_prob_cnn.basics.region import Region, check_region
from nbv_prob_cnn.gain.best_view import BestOriginView
from nbv_prob_cnn.gain.directions import check_directions, ray_directions
from nbv_prob_cnn.gain.march import march_options, ray_march
from nbv_prob_cnn.gain.reference import reference_ray_gains, reference_view_gains
from nbv_prob_cnn.gain.sampling import GainSensor
from nbv_prob_cnn.gain.settings import PAPER_GAIN, GainSettings
from nbv_prob_cnn.gain.variant import GAIN_VARIANTS

#: Ray-casting backends (defined once, in :mod:`nbv_prob_cnn.basics.modes`).
BACKENDS = BACKEND_NAMES

__all__ = [
    "BACKENDS", "ray_directions", "ray_gains", "each_origin_ray_gains", "origin_view_gains", "view_gains",
    "view_membership", "empty_origins", "best_origin_view", "best_origin_views", "BestOriginView", "GAIN_VARIANTS",
    "GainSensor", "GainSettings", "PAPER_GAIN",
]  # fmt: skip


def empty_origins(state: np.ndarray, stride: int = 1, region: Region | None = None) -> np.ndarray:
    """Empty cells of ``state`` in ``np.argwhere`` order; with ``stride > 1`` only cells whose
    every coordinate is a multiple of ``stride`` (3DT uses 2: one cell in 8). ``region``: only the
    cells of that box (clipped to the grid), at the cost of the box instead of the grid; the same
    cells, in the same order, as cutting the whole grid's list to the box."""
    corner = np.zeros(state.ndim, dtype=np.int64)
    if region is not None:
        lo, hi = check_region(region, state.shape)
        corner[:] = [-(-v // stride) * stride for v in lo]  # the box's first lattice cells: the grid's lattice
        inside = state[tuple(slice(int(a), b) for a, b in zip(corner, hi, strict=True))]
        return empty_origins(inside, stride) + corner
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
    settings: GainSettings = PAPER_GAIN,
) -> np.ndarray:
    """Normalised ray gain ``G_r(v, h) = H / (H + M)`` of docs/method.md#probabilistic-ray-casting-gain.

    Args:
        state: ternary ``int8`` grid ``C`` (2D or 3D).
        prob: probabilistic map ``P`` (float32, same shape, in [0, 1]); only read in unknown
            cells. Ignored (may be None) with ``settings.mode="ig"``.
        directions: ``(R, dims)`` unit vectors, e.g. from :func:`ray_directions`.
        r_max: maximum range ``N`` in cells; samples ``t = 0..r_max``.
        origins: ``(N, dims)`` integer cell indices; default: every empty cell
            (``np.argwhere`` order).
        backend: ``"opencl"``, ``"numpy"`` (reference) or ``"auto"`` (OpenCL if a device works).
        settings: mode, tolerance, minimum range, variant, sensor model and sampling
            (:class:`~nbv_prob_cnn.gain.settings.GainSettings`; default: the paper's gain).

    Returns:
        ``(N, R)`` float32 in [0, 1].

    Raises:
        ValueError: bad grid, probability map, directions, origins, range, settings or backend.
    """
    state, prob, directions, origins, backend = _check_gain_inputs(
        state, prob, directions, r_max, origins, backend, settings
    )
    options = march_options(state, prob, directions, r_max, settings)
    if backend == "numpy":
        return reference_ray_gains(state, prob, directions, r_max, origins, settings, options)
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    march = ray_march(state.ndim, directions, r_max, settings, options)
    return get_ray_caster().run(_grid_code(state, prob, settings), origins, march)


def each_origin_ray_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    origins: np.ndarray,
    backend: str = "auto",
    *,
    settings: GainSettings = PAPER_GAIN,
) -> np.ndarray:
    """:func:`ray_gains` of each origin along its own rays: ``directions`` ``(N, R, dims)``, origin
    ``i`` casting ``directions[i]`` (e.g. the rays through each of N camera images). ``(N, R)``
    float32; on OpenCL one launch of ``ray_gain`` marches each origin's rays alone.

    Raises:
        ValueError: as :func:`ray_gains`, or ``directions`` not ``(len(origins), R, dims)``.
    """
    directions = np.asarray(directions, dtype=np.float64)
    origins = np.asarray(origins)
    if directions.ndim != 3 or origins.ndim != 2 or directions.shape[0] != origins.shape[0]:
        raise ValueError(
            f"directions: expected (N, R, dims) rays for {origins.shape[:1]} origins, got {directions.shape}"
        )
    n, r, dims = directions.shape
    state, prob, flat, origins, backend = _check_gain_inputs(state, prob, directions.reshape(n * r, dims), r_max,
                                                             origins, backend, settings)  # fmt: skip
    if n == 0:
        return np.zeros((0, r), dtype=np.float32)
    options = march_options(state, prob, flat, r_max, settings)
    if backend == "numpy":  # the reference, origin by origin
        normals = None if options is None else options.normals
        own = flat.reshape(n, r, dims)
        return np.concatenate([
            reference_ray_gains(state, prob, own[i], r_max, origins[i : i + 1], settings,
                                march_options(state, prob, own[i], r_max, settings, normals))
            for i in range(n)
        ])  # fmt: skip
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    march = ray_march(state.ndim, flat, r_max, settings, options, groups=n)
    return get_ray_caster().run_each(_grid_code(state, prob, settings), origins, march)


def origin_view_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    membership: np.ndarray,
    origins: np.ndarray | None = None,
    backend: str = "auto",
    *,
    settings: GainSettings = PAPER_GAIN,
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
        state, prob, directions, r_max, origins, backend, settings
    )
    member = _check_membership(membership, directions)
    options = march_options(state, prob, directions, r_max, settings)
    if backend == "numpy":
        return reference_view_gains(state, prob, directions, r_max, member, origins, settings, options)
    from nbv_prob_cnn.gain.opencl import get_ray_caster

    march = ray_march(state.ndim, directions, r_max, settings, options)
    return get_ray_caster().run_views(_grid_code(state, prob, settings), origins, march, member)


def best_origin_view(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    membership: np.ndarray,
    origins: np.ndarray | None = None,
    backend: str = "auto",
    *,
    settings: GainSettings = PAPER_GAIN,
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
    (False: every view of every evaluated origin; the same result, for comparison). Other
    arguments: as :func:`origin_view_gains`.
    """
    state, prob, directions, origins, backend = _check_gain_inputs(
        state, prob, directions, r_max, origins, backend, settings
    )
    member = _check_membership(membership, directions)
    if origins.shape[0] == 0:
        return BestOriginView(-1, 0, 0.0)
    if backend == "numpy":
        gains = origin_view_gains(state, prob, directions, r_max, member, origins, "numpy", settings=settings)
        flat = int(np.argmax(gains))
        index = flat // gains.shape[1]
        return BestOriginView(index, flat % gains.shape[1], float(gains.flat[flat]), origins[index])
    index, views, gains = _bounded_search(state, prob, directions, r_max, member, origins, settings, block_size,
                                          prune_views, 1, None)  # fmt: skip
    if index.size == 0:  # no positive gain: the exhaustive argmax of zeros
        return BestOriginView(0, 0, 0.0, origins[0])
    return BestOriginView(int(index[0]), int(views[0]), float(gains[0]), origins[int(index[0])])


def best_origin_views(
    state: np.ndarray,
    prob: np.ndarray | None,
    directions: np.ndarray,
    r_max: int,
    membership: np.ndarray,
    origins: np.ndarray,
    top_k: int,
    allowed: np.ndarray | None = None,
    *,
    settings: GainSettings = PAPER_GAIN,
    block_size: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``top_k`` (origin, view) pairs of largest positive :func:`origin_view_gains`, best first
    (ties: the first origin, then the first view), by the coarse-to-fine search of
    :func:`best_origin_view` on OpenCL: ``(origin positions, views, gains)``, at most ``top_k``.
    ``allowed``: ``(N, V)`` bool, the views allowed at each origin (the others gain nothing).

    Raises:
        ValueError: bad inputs (as :func:`origin_view_gains`), ``top_k`` < 1 or ``allowed`` of another shape.
    """
    state, prob, directions, origins, _ = _check_gain_inputs(state, prob, directions, r_max, origins, "opencl",
                                                             settings)  # fmt: skip
    member = _check_membership(membership, directions)
    if isinstance(top_k, bool) or not isinstance(top_k, (int, np.integer)) or top_k < 1:
        raise ValueError(f"top_k: expected a positive integer, got {top_k!r}")
    if allowed is not None:
        allowed = np.asarray(allowed, dtype=bool)
        if allowed.shape != (origins.shape[0], member.shape[1]):
            expected = (origins.shape[0], member.shape[1])
            raise ValueError(f"allowed: expected a {expected} bool mask, got {allowed.shape}")
    if origins.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    return _bounded_search(state, prob, directions, r_max, member, origins, settings, block_size, True, top_k, allowed)


def _bounded_search(state, prob, directions, r_max, member, origins, settings, block_size, prune_views, top_k,
                    allowed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:meth:`~nbv_prob_cnn.gain.opencl.OpenCLRayCaster.best_views` on checked inputs."""
    from nbv_prob_cnn.gain.opencl import BOUND_BLOCK, get_ray_caster

    if block_size is not None and (not isinstance(block_size, (int, np.integer)) or block_size < 1):
        raise ValueError(f"block_size: expected a positive integer, got {block_size!r}")
    march = ray_march(state.ndim, directions, r_max, settings, march_options(state, prob, directions, r_max, settings))
    code = _grid_code(state, prob, settings)
    index, views, gains, _ = get_ray_caster().best_views(code, origins, march, member, top_k, allowed,
                                                         block_size=int(block_size or BOUND_BLOCK),
                                                         prune_views=prune_views)  # fmt: skip
    return index, views, gains


def _grid_code(state: np.ndarray, prob: np.ndarray | None, settings: GainSettings) -> np.ndarray:
    """The kernels' cell codes of ``state`` (with ``prob`` for the probabilistic mode)."""
    from nbv_prob_cnn.gain.marched_grid import encode_grid

    return encode_grid(state, prob if settings.mode == "prob" else None)


def _check_membership(membership: np.ndarray, directions: np.ndarray) -> np.ndarray:
    member = np.asarray(membership)
    if member.ndim != 2 or member.shape[0] != directions.shape[0] or not np.all((member == 0) | (member == 1)):
        raise ValueError(f"membership: expected a ({directions.shape[0]}, V) 0/1 matrix, got shape {member.shape}")
    return member


def _check_gain_inputs(state, prob, directions, r_max, origins, backend, settings):
    """Validate the shared arguments of the gain functions; resolve ``backend="auto"``."""
    state = check_state(state)
    if not isinstance(settings, GainSettings):
        raise ValueError(f"settings: expected a GainSettings, got {type(settings).__name__}")
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if not isinstance(r_max, (int, np.integer)) or not 1 <= r_max <= 4096:
        raise ValueError(f"r_max: expected an integer range in cells in [1, 4096], got {r_max!r}")
    if settings.mode == "prob":
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
