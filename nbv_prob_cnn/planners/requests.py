"""Turning a planning request (method name, sensor overrides, reachable box, origin budget)
into core calls, and chosen views into poses. Used by the ROS nodes; imports no ROS."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from nbv_prob_cnn.basics.camera import dataset_defaults
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.planners import GAIN_METHODS, GainMethod, PlanningContext, ViewChoice, make_planner, ros_method
from nbv_prob_cnn.planners.base import OriginFilter, ViewMask, bounded
from nbv_prob_cnn.planners.methods import GainPlanner


def gain_method(name: str, default: str) -> GainMethod:
    """The gain-based method called ``name`` (``""`` = ``default``); the oracle is refused.
    (Scoring given poses needs per-ray gains: only the gain-based methods can.)

    Raises:
        ValueError: unknown method or one that needs the ground truth.
    """
    name = name or default
    method = GAIN_METHODS.get(name)
    if method is None or method.probability == "oracle":
        allowed = sorted(m for m, spec in GAIN_METHODS.items() if spec.probability != "oracle")
        raise ValueError(f"unknown method {name!r}; expected one of {allowed}")
    return method


def planning_context(
    dataset: str,
    geometry: GridGeometry,
    backend: str,
    n_rays: int,
    rng: np.random.Generator,
    hfov_deg: float = 0.0,
    vfov_deg: float = 0.0,
    max_range_m: float = 0.0,
    min_range_m: float = 0.0,
) -> PlanningContext:
    """The data set's defaults with the node's/request's sensor overrides (0 = default).

    Raises:
        ValueError: dimensionality of the grid differs from the data set's, or bad overrides.
    """
    defaults = dataset_defaults(dataset)
    if defaults.dims != geometry.dims:
        raise ValueError(f"grid is {geometry.dims}D but the node is configured for {dataset!r} ({defaults.dims}D)")
    overrides = (("hfov_deg", hfov_deg), ("vfov_deg", vfov_deg), ("max_range_m", max_range_m),
                 ("min_range_m", min_range_m))  # fmt: skip
    for name, value in overrides:
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"{name}: expected a finite non-negative value (0 = default), got {value}")
    sensor = defaults.sensor
    if hfov_deg or vfov_deg or max_range_m or min_range_m:
        sensor = replace(
            sensor,
            hfov_deg=min(hfov_deg, 179.0) if hfov_deg else sensor.hfov_deg,
            vfov_deg=(min(vfov_deg, 179.0) if vfov_deg else sensor.vfov_deg) if defaults.dims == 3 else None,
            r_max=max(1, round(max_range_m / geometry.resolution)) if max_range_m else sensor.r_max,
            min_range=min_range_m / geometry.resolution if min_range_m else sensor.min_range,
        )
        if sensor.min_range >= sensor.r_max:
            raise ValueError(
                f"min_range_m ({sensor.min_range * geometry.resolution:g} m) must be below the maximum range "
                f"({sensor.r_max * geometry.resolution:g} m)"
            )
    return PlanningContext(defaults, rng=rng, backend=backend, n_rays=n_rays or None, sensor=sensor)


def origin_filter(
    geometry: GridGeometry,
    use_workspace: bool,
    box_min: np.ndarray,
    box_max: np.ndarray,
    max_origins: int,
    rng: np.random.Generator,
) -> Callable[[np.ndarray], np.ndarray]:
    """Keep origins inside the workspace box (if asked), then at most ``max_origins`` at random; with a
    workspace a :class:`~nbv_prob_cnn.planners.base.BoundedFilter` (candidates are listed in its cells)."""

    def apply(origins: np.ndarray) -> np.ndarray:
        if use_workspace:
            origins = origins[geometry.cells_in_box(origins, box_min, box_max)]
        if max_origins and origins.shape[0] > max_origins:
            origins = origins[np.sort(rng.choice(origins.shape[0], size=max_origins, replace=False))]
        return origins

    return bounded(geometry.box_region(box_min, box_max) if use_workspace else None, apply)


def flat_cells(cells: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Flat indices (x fastest, the order grids travel in) of cells ``(N, dims)``."""
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, len(shape))
    return np.asarray(np.ravel_multi_index(tuple(cells.T), shape, order="F"), dtype=np.int64)


def allowed_origins_filter(allowed_flat: np.ndarray, shape: tuple[int, ...]) -> Callable[[np.ndarray], np.ndarray]:
    """Keep the origins whose flat index (:func:`flat_cells`) is in ``allowed_flat``.

    Raises:
        ValueError: an index outside the grid.
    """
    allowed = np.asarray(allowed_flat, dtype=np.int64)
    if allowed.size and (allowed.min() < 0 or allowed.max() >= int(np.prod(shape))):
        raise ValueError(f"allowed_origins: flat cell indices must lie in [0, {int(np.prod(shape))})")

    def apply(origins: np.ndarray) -> np.ndarray:
        return origins[np.isin(flat_cells(origins, shape), allowed)]

    return apply


def view_pose(choice: ViewChoice, context: PlanningContext, geometry: GridGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Camera position (metres, cell centre) and optical-frame quaternion of a chosen view."""
    return geometry.cell_centre(choice.cell), context.view_quaternion(choice.view_index)


def choice_from_pose(
    position: np.ndarray, quaternion: np.ndarray, gain: float, context: PlanningContext, geometry: GridGeometry
) -> ViewChoice:
    """The inverse of :func:`view_pose`: the cell containing ``position`` and the candidate
    orientation nearest to ``quaternion`` (exact for poses made by :func:`view_pose`).

    Raises:
        ValueError: a position outside the grid.
    """
    cells, inside = geometry.containing_cell(np.asarray(position, dtype=np.float64).reshape(1, 3))
    if not inside[0]:
        raise ValueError(f"view position {list(position)} lies outside the grid")
    candidates = np.array([context.view_quaternion(i) for i in range(len(context.orientations))])
    q = np.asarray(quaternion, dtype=np.float64)
    view = int(np.argmax(np.abs(candidates @ (q / np.linalg.norm(q)))))
    return ViewChoice(cells[0].copy(), view, float(gain))


def rank_for_request(
    method: str,
    default: str,
    state: np.ndarray,
    context: PlanningContext,
    top_k: int,
    origin_filter: OriginFilter | None,
    given_probability: np.ndarray | None = None,
    view_mask: ViewMask | None = None,
) -> list[ViewChoice]:
    """What ``/nbv/rank_views`` runs: the registry planner of ``method`` in this process, with
    ``given_probability`` (the map the planner node got from ``/nbv/complete``) as its
    completion when one is sent, and ``view_mask`` (the request's ``allowed_views``) when given.

    Raises:
        ValueError: unknown method, an oracle, a probability map of another shape, or a view
            mask for a method whose search takes none.
    """
    spec = ros_method(method, default)
    if given_probability is not None:
        if given_probability.shape != state.shape:
            raise ValueError(f"probability grid {given_probability.shape} does not match grid {state.shape}")
        context.completion = lambda _state, _context, corner=None: given_probability
    context.ranker = None  # rank here
    planner = make_planner(spec.name)
    if view_mask is None:
        return planner.rank(state, context, max(1, int(top_k)), origin_filter)
    if not isinstance(planner, GainPlanner):
        raise ValueError(f"allowed_views: method {spec.name!r} takes no view mask (only the gain-based methods do)")
    return planner.rank(state, context, max(1, int(top_k)), origin_filter, view_mask=view_mask)
