"""What every planner shares: the planning context, the chosen view and the view search."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from nbv_prob_cnn.camera import DatasetDefaults, Sensor, dataset_defaults, orientations
from nbv_prob_cnn.gain import empty_origins, ray_directions, ray_gains, view_membership

#: Upper bound on origins × rays per ray-casting call (bounds memory for N_rays = 16).
MAX_RAYS_PER_CALL = 8_000_000


@dataclass
class PlanningContext:
    """Everything a planner may read besides the grid.

    Attributes:
        defaults: the data set's SPEC §7 parameters (sensor, N_rays, P0, stride…).
        rng: random generator (random planner, downsampled origins).
        ground_truth: the oracle's grid ``D`` (only the omniscient planner reads it).
        backend: ray-casting backend (``"auto"``, ``"opencl"``, ``"numpy"``).
        n_rays: sub-cells per side of the ray square/cube (default: the data set's).
        sensor: overrides the data set's sensor.
        eps: early-stop tolerance of the kernel (0 = exact).
    """

    defaults: DatasetDefaults
    rng: np.random.Generator = field(default_factory=np.random.default_rng)
    ground_truth: np.ndarray | None = None
    backend: str = "auto"
    n_rays: int | None = None
    sensor: Sensor | None = None
    eps: float = 0.0

    def __post_init__(self) -> None:
        sensor = self.active_sensor
        self.directions = ray_directions(self.defaults.dims, self.n_rays or self.defaults.n_rays)
        self.orientations = orientations(self.defaults.dims)
        self.membership = view_membership(self.directions, self.orientations, sensor.hfov_deg, sensor.vfov_deg)

    @classmethod
    def for_dataset(cls, name: str, **kwargs) -> PlanningContext:
        return cls(dataset_defaults(name), **kwargs)

    @property
    def active_sensor(self) -> Sensor:
        return self.sensor or self.defaults.sensor

    def candidate_origins(self, state: np.ndarray) -> np.ndarray:
        """Empty cells, on the data set's origin stride (1/8 of the cells on 3DT)."""
        return empty_origins(state, self.defaults.origin_stride)


@dataclass
class ViewChoice:
    """A chosen view: ``cell`` (grid index of the camera cell), ``view_index`` into
    ``context.orientations``, its ``gain`` and the seconds spent per stage."""

    cell: np.ndarray
    view_index: int
    gain: float
    times: dict[str, float] = field(default_factory=lambda: {"cnn": 0.0, "raycast": 0.0, "views": 0.0})


class Planner(Protocol):
    """A next-best-view method. ``plan`` returns None when no view has positive gain."""

    name: str

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None: ...


def search_best_view(
    state: np.ndarray,
    prob: np.ndarray | None,
    origins: np.ndarray,
    context: PlanningContext,
    mode: str = "prob",
) -> ViewChoice | None:
    """Argmax of ``G_W`` over ``origins`` × the context's orientations (SPEC §5).

    Ray gains are computed in blocks of origins (bounded memory) and each block is turned into
    view gains with one matrix product. Ties go to the first origin, then the first view.
    """
    sensor = context.active_sensor
    n_rays = context.directions.shape[0]
    block = max(1, MAX_RAYS_PER_CALL // n_rays)
    best = (-1.0, -1, -1)
    t_ray = t_view = 0.0
    for start in range(0, origins.shape[0], block):
        chunk = origins[start : start + block]
        t0 = time.perf_counter()
        gains = ray_gains(
            state,
            prob,
            context.directions,
            sensor.r_max,
            chunk,
            context.backend,
            mode=mode,
            eps=context.eps,
            min_range=sensor.min_range,
        )
        t1 = time.perf_counter()
        views = gains @ context.membership
        flat = int(np.argmax(views))
        value = float(views.flat[flat])
        if value > best[0]:
            best = (value, start + flat // views.shape[1], flat % views.shape[1])
        t_view += time.perf_counter() - t1
        t_ray += t1 - t0
    if best[0] <= 0.0:
        return None
    return ViewChoice(origins[best[1]].copy(), int(best[2]), best[0], {"cnn": 0.0, "raycast": t_ray, "views": t_view})
