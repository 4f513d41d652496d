"""What every planner shares: the planning context, the chosen view and the view search."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor, dataset_defaults, orientations, yaw_quaternion
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.modes import CNN_PRECISIONS
from nbv_prob_cnn.basics.region import Region
from nbv_prob_cnn.basics.view_pose import ViewPose, view_pose
from nbv_prob_cnn.gain import (
    best_origin_view,
    best_origin_views,
    empty_origins,
    origin_view_gains,
    ray_directions,
    view_membership,
)
from nbv_prob_cnn.gain.original_sets import original_view_set
from nbv_prob_cnn.gain.sampling import GainSensor, check_sampling, check_sensor_model
from nbv_prob_cnn.gain.settings import DEFAULT_SURFACE_BLEND, GainSettings
from nbv_prob_cnn.gain.variant import check_variant, ig_min_range, uses_free_hits
from nbv_prob_cnn.planners.candidates import crop_to_reach

#: Ray and orientation sets of :class:`PlanningContext`: the paper's, or the authors' code's.
VIEW_SETS = ("spec", "original")
#: Ray range (cells) from which searches bound larger blocks (:func:`bound_block_size`).
LONG_RAYS = 64
#: Views a surface method re-ranks by their own image rays (:attr:`PlanningContext.image_rerank`).
#: 3DT, 10 worlds x 30 views with the view guard: 95 % of the surface after 9.9 views against 12.4
#: without (studies/results/surface/3dt_rerank).
DEFAULT_IMAGE_RERANK = 20
#: Upper bound on origins × views per gain call (bounds the (origins, views) gains in memory).
MAX_VIEWS_PER_CALL = 64_000_000


class CompletionHook(Protocol):
    """``completion(state, context, corner=None) -> P``: a probabilistic map of ``state``
    (docs/method.md#completion-cnn); ``corner``: where ``state`` starts in the context's grid
    (cells) when it is a window of it (the CNN window), None for the whole grid."""

    def __call__(
        self, state: np.ndarray, context: PlanningContext, /, corner: tuple[int, ...] | None = None
    ) -> np.ndarray: ...


#: ``ranker(method, state, prob, top_k) -> views``: the ``top_k`` best views of a method, best first.
RankHook = Callable[[str, np.ndarray, "np.ndarray | None", int], "list[ViewChoice]"]
#: Narrows candidate origins (e.g. to a reachable box): ``(N, dims) -> (M, dims)``.
OriginFilter = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class BoundedFilter:
    """An origin filter whose kept origins all lie in the cell box ``region``: the planners list
    candidates in that box alone (:func:`filtered_origins`), at the cost of the box instead of the
    grid (a 1.5 m workspace in the 29.7 M-cell kitchen: 1.1 s of a 3.7 s step went to listing every
    empty cell of the room). ``keep`` is the filter proper."""

    region: Region
    keep: OriginFilter

    def __call__(self, origins: np.ndarray) -> np.ndarray:
        return self.keep(origins)


def bounded(region: Region | None, keep: OriginFilter) -> OriginFilter:
    """``keep`` as a :class:`BoundedFilter` of ``region`` (every origin it keeps lies there), or itself
    when there is no region."""
    return keep if region is None else BoundedFilter(region, keep)


def filter_region(origin_filter: OriginFilter | None) -> Region | None:
    """The cell box all origins that ``origin_filter`` keeps lie in (None: anywhere)."""
    return origin_filter.region if isinstance(origin_filter, BoundedFilter) else None


def filtered_origins(state: np.ndarray, context: PlanningContext, origin_filter: OriginFilter | None) -> np.ndarray:
    """The context's candidate origins that ``origin_filter`` keeps, listed in its box alone when it
    has one: the same origins, in the same order, as filtering every candidate of the grid."""
    origins = context.candidate_origins(state, filter_region(origin_filter))
    return origins if origin_filter is None else origin_filter(origins)


#: Allowed orientations at origins: ``(N, 3)`` cells → ``(N, V)`` bool (e.g. a capability map).
ViewMask = Callable[[np.ndarray], np.ndarray]


@dataclass
class PlanningContext:
    """Everything a planner may read besides the grid.

    Attributes:
        defaults: the data set's parameters (docs/method.md#parameters-per-data-set: sensor, N_rays, P0, stride…).
        rng: random generator (random planner, downsampled origins).
        ground_truth: the oracle's grid ``D`` (only the omniscient planner reads it).
        backend: ray-casting backend (``"auto"``, ``"opencl"``, ``"numpy"``).
        n_rays: sub-cells per side of the ray square/cube (default: the data set's).
        sensor: overrides the data set's sensor.
        eps: early-stop tolerance of the kernel (0 = exact).
        completion: hook ``completion(state, context) -> P`` that replaces the local completion
            CNN (e.g. a call to the ``/nbv/complete`` server). None: the CNN in this process.
        ranker: hook ``ranker(method, state, prob, top_k) -> [ViewChoice]`` that replaces the
            local view search (e.g. a call to ``/nbv/rank_views``); ``prob`` is the completed map
            for CNN-probability methods, else None. None: search in this process.
        origin_stride: overrides the data set's origin stride (1 = every empty cell).
        gain_variant: ``"paper"`` (docs/method.md: gain, candidate views) or ``"original"`` (the authors' host choices,
            :mod:`nbv_prob_cnn.gain.variant`, docs/original_code.md).
        view_set: ``"spec"`` (the rays and orientations of docs/method.md: gain, candidate views) or ``"original"``
        (the authors'
            ray and orientation sets, :mod:`nbv_prob_cnn.gain.original_sets`; not with ``n_rays``).
        sensor_model: ``"paper"`` (the default) or ``"returns"``: the gain counts a cell by the
            probability that ``gain_sensor`` measures it (docs/sensing.md; gain-based methods).
        gain_sensor: the sensor's ranges, grazing limit and walls
            (:class:`~nbv_prob_cnn.gain.sampling.GainSensor`, e.g. ``GainSensor.from_noise``); read
            with ``sensor_model="returns"`` only, which needs it.
        sampling: ``"rounded"`` (docs/method.md, the default) or ``"exact"`` voxel traversal of the
            gain's rays (docs/sensing.md).
        cnn_window: None (the default): the completion CNN runs, exactly, over the cells the candidates'
            rays can read; a margin in cells: only over the candidates' box grown by it, with ``p0``
            outside (:mod:`nbv_prob_cnn.planners.local_completion`, docs/performance.md#scale).
        cnn_precision: the completion CNN's arithmetic in this process (``"float32"``, the default, or
            ``"bfloat16"``: :data:`~nbv_prob_cnn.basics.modes.CNN_PRECISIONS`).
        surface_blend: the surface methods' blend ``beta`` in [0, 1] (docs/method.md#surface-gain;
            :data:`DEFAULT_SURFACE_BLEND`); the paper's methods ignore it.
        image_rerank: the surface methods take the view search's best ``image_rerank`` views and
            re-rank them by rays through each view's own image
            (:mod:`~nbv_prob_cnn.planners.image_rays`, docs/method.md#re-ranking-by-the-image-rays);
            0 or 1: the search's order. The paper's methods ignore it.
    """

    defaults: DatasetDefaults
    rng: np.random.Generator = field(default_factory=np.random.default_rng)
    ground_truth: np.ndarray | None = None
    backend: str = "auto"
    n_rays: int | None = None
    sensor: Sensor | None = None
    eps: float = 0.0
    completion: CompletionHook | None = None
    ranker: RankHook | None = None
    origin_stride: int | None = None
    gain_variant: str = "paper"
    view_set: str = "spec"
    sensor_model: str = "paper"
    gain_sensor: GainSensor | None = None
    sampling: str = "rounded"
    cnn_window: int | None = None
    cnn_precision: str = "float32"
    surface_blend: float = DEFAULT_SURFACE_BLEND
    image_rerank: int = DEFAULT_IMAGE_RERANK

    def __post_init__(self) -> None:
        if self.cnn_precision not in CNN_PRECISIONS:
            raise ValueError(f"cnn_precision: expected one of {CNN_PRECISIONS}, got {self.cnn_precision!r}")
        check_variant(self.gain_variant)
        check_sampling(self.sampling)
        if not (isinstance(self.surface_blend, (int, float)) and 0.0 <= self.surface_blend <= 1.0):
            raise ValueError(f"surface_blend: expected a blend in [0, 1], got {self.surface_blend!r}")
        rerank = self.image_rerank
        if isinstance(rerank, bool) or not isinstance(rerank, (int, np.integer)) or rerank < 0:
            raise ValueError(f"image_rerank: expected a number of views >= 0 (0: no re-ranking), got {rerank!r}")
        if check_sensor_model(self.sensor_model) == "returns" and self.gain_sensor is None:
            raise ValueError("sensor_model 'returns' needs gain_sensor: the sensor's ranges (GainSensor)")
        if (self.sensor_model != "paper" or self.sampling != "rounded") and self.gain_variant != "paper":
            raise ValueError(f"sensor_model/sampling: only with gain_variant 'paper', got {self.gain_variant!r}")
        if self.view_set not in VIEW_SETS or (self.view_set == "original" and self.n_rays):
            raise ValueError(f"view_set: expected one of {VIEW_SETS} ('original': no n_rays), got {self.view_set!r}")
        if self.origin_stride is not None and (not isinstance(self.origin_stride, int) or self.origin_stride < 1):
            raise ValueError(f"origin_stride: expected a positive integer, got {self.origin_stride!r}")
        if self.cnn_window is not None and (not isinstance(self.cnn_window, int) or self.cnn_window < 0):
            raise ValueError(f"cnn_window: expected a margin in cells >= 0 or None, got {self.cnn_window!r}")
        sensor = self.active_sensor
        self.directions = ray_directions(self.defaults.dims, self.n_rays or self.defaults.n_rays)
        self.orientations = orientations(self.defaults.dims)
        self.membership = view_membership(self.directions, self.orientations, sensor.hfov_deg, sensor.vfov_deg)
        if self.view_set == "original":
            self.directions, self.orientations, self.membership = original_view_set(
                self.defaults.dims, sensor.hfov_deg, sensor.vfov_deg
            )

    @classmethod
    def for_dataset(cls, name: str, **kwargs) -> PlanningContext:
        return cls(dataset_defaults(name), **kwargs)

    @property
    def active_sensor(self) -> Sensor:
        return self.sensor or self.defaults.sensor

    @property
    def returns_sensor(self) -> GainSensor | None:
        """The sensor the gain knows: ``gain_sensor`` with ``sensor_model="returns"``, else None."""
        return self.gain_sensor if self.sensor_model == "returns" else None

    def gain_settings(self, mode: str = "prob", probability: str | None = None, surface: bool = False) -> GainSettings:
        """The gain settings of a view search in ``mode`` on a map from ``probability`` (``"constant"``,
        ``"cnn"``, ``"oracle"``), which the ``original`` gain variant treats differently
        (:func:`~nbv_prob_cnn.gain.variant.uses_free_hits`, :func:`~nbv_prob_cnn.gain.variant.ig_min_range`).
        ``surface``: a surface method's search (the blend :attr:`surface_blend`; the paper's variant only).

        Raises:
            ValueError: a surface search with the ``original`` gain variant.
        """
        variant, min_range = self.gain_variant, self.active_sensor.min_range
        if surface and variant != "paper":
            raise ValueError(f"gain_variant: the surface methods use the paper's variant, got {variant!r}")
        free_hits = mode == "prob" and uses_free_hits(variant, probability)
        min_range = ig_min_range(variant, min_range) if mode == "ig" else min_range
        blend = float(self.surface_blend) if surface else 0.0
        return GainSettings(mode, self.eps, min_range, variant, free_hits, self.returns_sensor, self.sampling, blend)

    def view_quaternion(self, view_index: int) -> np.ndarray:
        """Quaternion (x, y, z, w) of a candidate orientation (2D: the yaw about +z)."""
        orientation = self.orientations[view_index]
        if self.defaults.dims == 2:
            return yaw_quaternion(float(orientation))
        return np.asarray(orientation, dtype=np.float64)

    def candidate_origins(self, state: np.ndarray, region: Region | None = None) -> np.ndarray:
        """Empty cells, on the origin stride (default: the data set's); ``region``: of that cell box only."""
        return empty_origins(state, self.origin_stride or self.defaults.origin_stride, region)


@dataclass
class ViewChoice:
    """A chosen view: ``cell`` (grid index of the camera cell), ``view_index`` into
    ``context.orientations``, its ``gain`` and the seconds spent per stage. ``surface_estimate``
    (gain-based methods): computes the most new surface, in cells, a view of the ranking's candidates
    is expected to add on the map it was planned on (:func:`~nbv_prob_cnn.planners.surface_stop.best_new_surface`,
    the stop rule's number; on demand: a second view search). ``image_gain``: the view's gain over
    rays through its own image when a surface method re-ranked it
    (:func:`~nbv_prob_cnn.planners.image_rays.rerank_by_image`), else None."""

    cell: np.ndarray
    view_index: int
    gain: float
    times: dict[str, float] = field(default_factory=lambda: {"cnn": 0.0, "raycast": 0.0, "views": 0.0})
    surface_estimate: Callable[[], float] | None = field(default=None, repr=False, compare=False)
    image_gain: float | None = field(default=None, compare=False)

    def pose(self, geometry: GridGeometry, orientations: np.ndarray | None = None) -> ViewPose:
        """This view as a pose: the cell centre in metres and the quaternion ``(x, y, z, w)`` in the
        frame of a grid placed by ``geometry`` (:func:`~nbv_prob_cnn.basics.view_pose.view_pose`)."""
        return view_pose(np.asarray(self.cell), self.view_index, geometry, orientations, gain=self.gain)


class Planner(Protocol):
    """A next-best-view method. ``rank`` returns the ``top_k`` best views, best first (empty when
    no view has positive gain); ``plan`` the best one or None."""

    name: str

    def rank(
        self, state: np.ndarray, context: PlanningContext, top_k: int = 1, origin_filter: OriginFilter | None = None
    ) -> list[ViewChoice]: ...

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None: ...


class RankingPlanner:
    """Base of the planners: ``rank`` goes to ``context.ranker`` when one is set (the remote
    path), else to :meth:`rank_here`; ``plan`` is the first ranked view."""

    name: str = ""

    def rank(
        self, state: np.ndarray, context: PlanningContext, top_k: int = 1, origin_filter: OriginFilter | None = None
    ) -> list[ViewChoice]:
        if context.ranker is not None:
            return context.ranker(self.name, state, None, top_k)
        return self.rank_here(state, context, top_k, origin_filter)

    def rank_here(
        self, state: np.ndarray, context: PlanningContext, top_k: int, origin_filter: OriginFilter | None
    ) -> list[ViewChoice]:
        raise NotImplementedError

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        found = self.rank(state, context)
        return found[0] if found else None


def search_views(
    state: np.ndarray,
    prob: np.ndarray | None,
    origins: np.ndarray,
    context: PlanningContext,
    mode: str = "prob",
    top_k: int = 1,
    prune: bool = True,
    prune_views: bool = True,
    view_mask: ViewMask | None = None,
    probability: str | None = None,
    surface: bool = False,
) -> list[ViewChoice]:
    """The ``top_k`` (origin, orientation) pairs with the largest ``G_W``, best first
    (docs/method.md#candidate-views-and-view-gain).

    View gains are computed in blocks of origins (bounded memory) by
    :func:`~nbv_prob_cnn.gain.origin_view_gains`. Ties go to the first origin, then the first view.
    Views with zero gain are never returned. On OpenCL (and ``prune``) the exact coarse-to-fine
    search :func:`~nbv_prob_cnn.gain.best_origin_view` (``top_k`` 1) or
    :func:`~nbv_prob_cnn.gain.best_origin_views` finds the same views without evaluating origins
    that provably cannot reach the ``top_k``-th best gain (``prune_views``: nor views; False
    evaluates every view of the origins it evaluates, for comparison, and with ``top_k`` > 1 every
    origin). ``view_mask`` (optional) gives the orientations allowed at each origin; the others
    count as zero gain (never returned).
    ``probability``: the source of ``prob`` (``"constant"``, ``"cnn"``, ``"oracle"``), which the
    ``original`` gain variant treats differently (:func:`~nbv_prob_cnn.gain.variant.uses_free_hits`).
    ``surface``: the surface gain (a surface method; :meth:`PlanningContext.gain_settings`).
    The rays read only the box the origins' reach spans (:func:`~nbv_prob_cnn.planners.candidates.crop_to_reach`):
    the search runs on that part of the grid, with the same result.
    """
    sensor = context.active_sensor
    settings = context.gain_settings(mode, probability, surface)
    state, prob, origins, shift = crop_to_reach(state, prob, origins, sensor.r_max)
    if view_mask is not None and np.any(shift):
        view_mask = functools.partial(_shifted_mask, view_mask, shift)
    n_views = context.membership.shape[1]
    if prune and _uses_opencl(context.backend) and origins.shape[0] > 0 and (top_k == 1 or prune_views):
        t0 = time.perf_counter()
        stride = context.origin_stride or context.defaults.origin_stride
        block = bound_block_size(state.ndim, stride, sensor.r_max, surface=settings.surface > 0.0)
        if top_k == 1 and view_mask is None:
            one = best_origin_view(
                state, prob, context.directions, sensor.r_max, context.membership, origins, "opencl",
                settings=settings, block_size=block, prune_views=prune_views,
            )  # fmt: skip
            index, view, gain = np.array([one[0]]), np.array([one[1]]), np.array([one[2]])
        else:
            allowed = None if view_mask is None else _checked_mask(view_mask, origins, n_views)
            index, view, gain = best_origin_views(
                state, prob, context.directions, sensor.r_max, context.membership, origins, top_k, allowed,
                settings=settings, block_size=block,
            )  # fmt: skip
        times = {"cnn": 0.0, "raycast": time.perf_counter() - t0, "views": 0.0}
        return [
            ViewChoice(origins[i] + shift, int(w), float(g), dict(times))
            for i, w, g in zip(index.tolist(), view.tolist(), gain.tolist(), strict=True)
            if g > 0.0
        ]
    block = max(1, MAX_VIEWS_PER_CALL // n_views)
    kept_gain = np.zeros(0, dtype=np.float32)
    kept_index = np.zeros(0, dtype=np.int64)  # flat index origin * n_views + view
    t_ray = t_view = 0.0
    for start in range(0, origins.shape[0], block):
        chunk = origins[start : start + block]
        t0 = time.perf_counter()
        views = origin_view_gains(
            state, prob, context.directions, sensor.r_max, context.membership, chunk, context.backend, settings=settings
        )
        if view_mask is not None:
            views = np.where(_checked_mask(view_mask, chunk, n_views), views, 0.0).astype(views.dtype, copy=False)
        views = views.ravel()
        t1 = time.perf_counter()
        k = min(top_k, views.size)
        if k == 1:
            best = np.array([np.argmax(views)])  # the first of equal maxima
        else:  # only positive gains are returned: select among those (most views of a masked or
            # explored grid have none, and a selection over all of them cost more than the ray casting)
            best = np.flatnonzero(views > 0.0)
            if k < best.size:
                best = best[np.argpartition(views[best], best.size - k)[best.size - k :]]
        kept_gain = np.concatenate([kept_gain, views[best]])
        kept_index = np.concatenate([kept_index, best + start * n_views])
        order = np.lexsort((kept_index, -kept_gain))[:top_k]  # gain descending, then index
        kept_gain, kept_index = kept_gain[order], kept_index[order]
        t_view += time.perf_counter() - t1
        t_ray += t1 - t0
    times = {"cnn": 0.0, "raycast": t_ray, "views": t_view}
    positive = kept_gain > 0.0
    kept_gain, kept_index = kept_gain[positive], kept_index[positive]
    cells = origins[kept_index // n_views] + shift  # a copy: one row per choice
    return [
        ViewChoice(cell, int(view), float(g), dict(times))
        for cell, view, g in zip(cells, (kept_index % n_views).tolist(), kept_gain.tolist(), strict=True)
    ]


def bound_block_size(dims: int, stride: int, r_max: int, surface: bool = False) -> int:
    """Origins per axis of a bounded block of the coarse-to-fine search (a block of ``s`` strides holds
    about ``s**dims`` origins); for rays of :data:`LONG_RAYS` cells or more, whose bound pass costs
    more than the exact origins looser bounds let through, three strides (and at least 4 cells in 3D),
    four for a ``surface`` blend, whose bounds by dynamic programming cost more per block; for shorter
    rays three strides, two for a ``surface`` blend.
    Measured (one search; seconds summed over the grids, best of 3-5):

    * 3DT (range 128): every cell 1.25 -> 0.53 s (b 2 -> 4), 256x256x192 30.6 -> 9.9 s (half-explored,
      a 2-core CPU shared with other jobs). Stride 2, CPU seconds over 12 grids of ``cnn_surface``
      explorations (3 worlds, after 2, 5, 10 and 20 views), b 4 / 6 / 8 / 10: the paper's gain 4.30 /
      4.01 / 4.48 / 5.40, the surface gain's top 20 8.10 / 5.76 / 5.69 / 6.24 (measured while its bounds
      by dynamic programming still gathered each bound ray's samples twice).
    * 2D (range 128, every cell), idle, b 2 / 3 / 4: 3 half-explored maps, the paper's gain 0.256 / 0.168
      / 0.156, the surface gain's top 20 0.350 / 0.220 / 0.185; 5 grids of a ``cnn_surface`` exploration
      0.206 / 0.164 / 0.178 and 0.256 / 0.205 / 0.212.
    * 3DU (range 24): half-explored 0.33 -> 0.71 s (b 2 -> 4). Idle, b 2 / 3, 12 grids of ``cnn_surface``
      explorations: the paper's gain 0.356 / 0.324 s, the surface gain's top 20 0.407 / 0.493 s; 3
      half-explored grids 0.139 / 0.107 and 0.169 / 0.218 s: 3 strides for the paper's gain, 2 for a
      surface blend there.
    """
    if r_max >= LONG_RAYS:
        strides = (4 if surface else 3) * stride
        return max(4, strides) if dims == 3 else strides
    return (2 if surface else 3) * stride


def _checked_mask(view_mask: ViewMask, origins: np.ndarray, n_views: int) -> np.ndarray:
    """``view_mask(origins)`` as an ``(N, n_views)`` bool array.

    Raises:
        ValueError: the mask has another shape.
    """
    allowed = np.asarray(view_mask(origins), dtype=bool)
    if allowed.shape != (origins.shape[0], n_views):
        raise ValueError(f"view_mask: expected a {(origins.shape[0], n_views)} bool mask, got shape {allowed.shape}")
    return allowed


def _shifted_mask(view_mask: ViewMask, shift: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``view_mask`` of cells of a cropped grid (``shift``: the crop's corner in the whole grid)."""
    return view_mask(cells + shift)


def _uses_opencl(backend: str) -> bool:
    if backend == "auto":
        from nbv_prob_cnn.basics.cl_device import opencl_available

        return opencl_available()
    return backend == "opencl"


def search_best_view(
    state: np.ndarray,
    prob: np.ndarray | None,
    origins: np.ndarray,
    context: PlanningContext,
    mode: str = "prob",
) -> ViewChoice | None:
    """The argmax of ``G_W`` over ``origins`` × orientations, or None if every gain is 0."""
    found = search_views(state, prob, origins, context, mode, top_k=1)
    return found[0] if found else None
