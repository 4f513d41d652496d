"""Planning on a saved grid, without ROS: the best views with their poses, and the best gain of
every candidate origin (for a heat map).

This is what ``nbv plan --grid`` and ``nbv view --grid`` run. The grid carries its placement
(:class:`~nbv_prob_cnn.basics.geometry.GridGeometry`); the data set supplies the sensor, the rays
and, for the CNN methods, the weights. Methods that need the ground truth (``omniscient``) are
refused: a saved grid has none.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.camera import optical_axis
from nbv_prob_cnn.basics.datasets import DATASET_SPECS
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.view_pose import ViewPose
from nbv_prob_cnn.gain import origin_view_gains
from nbv_prob_cnn.planners.base import MAX_VIEWS_PER_CALL, OriginFilter, PlanningContext, ViewChoice, bounded
from nbv_prob_cnn.planners.methods import GAIN_METHODS, method_origins, probability_map
from nbv_prob_cnn.planners.registry import METHODS, make_planner

#: Columns of :func:`write_views_csv`, units in the names (``_m`` metres; the quaternion is unitless).
VIEWS_CSV_COLUMNS = ["rank", "gain", "cell_x", "cell_y", "cell_z", "view_index",
                     "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]  # fmt: skip


def infer_dataset(shape: Sequence[int], dataset: str | None = None) -> str:
    """The data set whose defaults (sensor, rays, weights) apply to a grid of ``shape``:
    ``dataset`` when given, else the one with exactly this shape, else ``3dt`` for 3D (the
    integrator's default box) and ``2d`` for 2D.

    Raises:
        ValueError: an unknown data set, or one of the other dimensionality.
    """
    dims = len(shape)
    if dataset is None:
        same = [name for name, spec in DATASET_SPECS.items() if tuple(spec.shape) == tuple(shape)]
        dataset = same[0] if same else ("3dt" if dims == 3 else "2d")
    if dataset not in DATASET_SPECS:
        raise ValueError(f"dataset: expected one of {sorted(DATASET_SPECS)}, got {dataset!r}")
    if len(DATASET_SPECS[dataset].shape) != dims:
        raise ValueError(f"dataset {dataset!r} is {len(DATASET_SPECS[dataset].shape)}D, the grid is {dims}D")
    return dataset


def resolution_note(dataset: str, geometry: GridGeometry) -> str | None:
    """A note when the grid's cells differ from the data set's (the sensor range is in cells), else None."""
    spec = DATASET_SPECS[dataset]
    if abs(geometry.resolution - spec.resolution_m) <= 0.01 * spec.resolution_m:
        return None
    return (
        f"note: the grid's cells are {geometry.resolution * 100:.3g} cm, the {dataset} sensor model's "
        f"{spec.resolution_m * 100:.3g} cm; its range of {spec.sensor.r_max} cells is "
        f"{spec.sensor.r_max * geometry.resolution:.2f} m here (--dataset picks another model)"
    )


def check_offline_method(method: str) -> None:
    """Raise ``ValueError`` for an unknown method or one that needs the ground truth."""
    spec = METHODS.get(method)
    if spec is None or spec.needs_ground_truth:
        allowed = sorted(m for m, s in METHODS.items() if not s.needs_ground_truth)
        why = "needs the ground truth, which a saved grid does not have" if spec else "is not a method"
        raise ValueError(f"method {method!r} {why}; use one of {allowed}")


def workspace_filter(geometry: GridGeometry, workspace_m: Sequence[float] | None) -> OriginFilter | None:
    """Keep the origins whose cell centre lies in the box ``(xmin, ymin[, zmin], xmax, ymax[, zmax])``
    in metres (None: no box).

    Raises:
        ValueError: not 2 × dims finite bounds with min <= max.
    """
    if workspace_m is None:
        return None
    bounds = np.asarray(workspace_m, dtype=np.float64).reshape(-1)
    dims = geometry.dims
    if bounds.size != 2 * dims:
        raise ValueError(f"workspace: expected {2 * dims} numbers (min then max per axis, m), got {bounds.size}")
    lo, hi = np.zeros(3), np.zeros(3)
    lo[:dims], hi[:dims] = bounds[:dims], bounds[dims:]
    geometry.cells_in_box(np.zeros((0, dims), dtype=np.int64), lo, hi)  # validates the bounds

    def inside(origins: np.ndarray) -> np.ndarray:
        return origins[geometry.cells_in_box(origins, lo, hi)]

    return bounded(geometry.box_region(lo, hi), inside)


def plan_views(
    state: np.ndarray,
    geometry: GridGeometry,
    dataset: str,
    method: str = "cnn_prob",
    top_k: int = 10,
    workspace_m: Sequence[float] | None = None,
    backend: str = "auto",
    seed: int = 0,
    times: dict[str, float] | None = None,
    cnn_window: int | None = None,
    cnn_precision: str = "float32",
) -> list[ViewPose]:
    """The ``top_k`` best views of ``method`` on ``state``, best first, as poses (empty when no
    view has a positive gain). ``times``, when given, receives the seconds of the search's stages
    (``cnn``, ``raycast``, ``views``). ``cnn_window`` and ``cnn_precision``: the CNN's window margin
    (cells; None: every cell the rays read) and arithmetic (:class:`~nbv_prob_cnn.planners.base.PlanningContext`).

    Raises:
        ValueError: bad method, data set, ``top_k`` or workspace; missing CNN weights
            (:class:`~nbv_prob_cnn.completion.inference.WeightsError`, naming the ``nbv train`` command).
    """
    check_offline_method(method)
    if not isinstance(top_k, int) or top_k < 1:
        raise ValueError(f"top_k: expected a positive integer, got {top_k!r}")
    context = PlanningContext.for_dataset(
        infer_dataset(state.shape, dataset), rng=np.random.default_rng(seed), backend=backend,
        cnn_window=cnn_window, cnn_precision=cnn_precision,
    )  # fmt: skip
    # 3D: a view and the same view rolled about its optical axis are one view (nbv_planner's arm_roll_symmetric);
    # each axis has two rolls, so twice top_k ranked views hold top_k distinct ones
    wanted = 2 * top_k if state.ndim == 3 else top_k
    ranked = make_planner(method).rank(state, context, wanted, workspace_filter(geometry, workspace_m))
    if times is not None and ranked:
        times.update(ranked[0].times)
    distinct = one_per_optical_axis(ranked, context.orientations) if state.ndim == 3 else ranked
    return [choice.pose(geometry, context.orientations) for choice in distinct[:top_k]]


def one_per_optical_axis(ranked: Sequence[ViewChoice], orientations: np.ndarray) -> list[ViewChoice]:
    """``ranked`` (best first, 3D) without the views that differ from a better one only by a roll about
    the optical axis (same cell, same viewing direction; ``orientations``: quaternions by view index)."""
    seen: set[tuple] = set()
    kept = []
    for choice in ranked:
        axis = optical_axis(orientations[choice.view_index], 3)
        key = (tuple(int(v) for v in choice.cell), tuple(np.round(axis, 6)))
        if key not in seen:
            seen.add(key)
            kept.append(choice)
    return kept


def best_gain_per_origin(
    state: np.ndarray,
    geometry: GridGeometry,
    dataset: str,
    method: str = "prob_ig",
    workspace_m: Sequence[float] | None = None,
    backend: str = "auto",
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Every candidate origin of a gain method and the gain of its best view.

    Returns:
        ``(origins (N, dims) cell indices, best gains (N,) float32)``.

    Raises:
        ValueError: a method that is not gain-based (``random``, the City-CNNs) or needs the
            ground truth, or bad inputs as :func:`plan_views`.
    """
    check_offline_method(method)
    if method not in GAIN_METHODS:
        raise ValueError(f"method {method!r}: a gain heat map needs a gain method, one of "
                         f"{sorted(m for m in GAIN_METHODS if m != 'omniscient')}")  # fmt: skip
    gain_method = GAIN_METHODS[method]
    context = PlanningContext.for_dataset(infer_dataset(state.shape, dataset), rng=np.random.default_rng(seed),
                                          backend=backend)  # fmt: skip
    prob = probability_map(gain_method, state, context)
    origins = method_origins(gain_method, state, context, workspace_filter(geometry, workspace_m))
    sensor = context.active_sensor
    block = max(1, MAX_VIEWS_PER_CALL // context.membership.shape[1])
    best = np.zeros(origins.shape[0], dtype=np.float32)
    for start in range(0, origins.shape[0], block):
        gains = origin_view_gains(
            state, prob, context.directions, sensor.r_max, context.membership, origins[start : start + block],
            context.backend, settings=context.gain_settings(gain_method.mode, surface=gain_method.surface),
        )  # fmt: skip
        best[start : start + block] = gains.max(axis=1)
    return origins, best


def write_views_csv(poses: Sequence[ViewPose], path: str | Path) -> Path:
    """Write ranked views (best first) with the columns of :data:`VIEWS_CSV_COLUMNS`."""
    import csv

    path = Path(path)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(VIEWS_CSV_COLUMNS)
        for rank, pose in enumerate(poses, start=1):
            cell = list(pose.cell) + [""] * (3 - len(pose.cell))
            position = [f"{v:.5f}" for v in pose.position_m]
            quaternion = [f"{v:.6f}" for v in pose.quaternion_xyzw]
            writer.writerow([rank, f"{pose.gain:.6g}", *cell, pose.view_index, *position, *quaternion])
    return path
