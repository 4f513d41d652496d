"""When to stop looking: the surface a planned view is expected to add, in cells, and the stop rule
on it (docs/method.md#stopping-when-the-surface-is-finished).

The surface term of a ray (:attr:`~nbv_prob_cnn.gain.settings.GainSettings.surface` 1) is
``S_r = Σ_t u_t w_t Pr(r_t) p_t / Σ_t w_t``: the expected weight of the unknown cell where its
return lands. A ray of solid angle ``Ω_r`` (radians in 2D) meets at distance ``t`` cells a patch of
about ``Ω_r t^nu`` cells (``w_t = t^nu``: ``t`` in 2D, ``t²`` in 3D), so the view's expected new
surface is about ``Σ_r Ω_r S_r Σ_t w_t`` cells, with ``Ω_r`` the view's angle (2D: its field of view;
3D: the solid angle of its frustum) shared equally by its rays. An estimate: the rays are not
spread exactly evenly, and a surface seen obliquely holds more cells than its patch across the ray.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.gain import ray_gains
from nbv_prob_cnn.gain.directions import distance_weights
from nbv_prob_cnn.gain.settings import GainSettings


def predicted_new_surface(state: np.ndarray, prob: np.ndarray, cell: np.ndarray, view_index: int, context) -> float:
    """The expected number of surface cells, unknown now, that the view ``(cell, view_index)`` of
    ``context`` (a :class:`~nbv_prob_cnn.planners.base.PlanningContext`) sees: the module's estimate
    on the occupancy map ``prob`` (read in unknown cells). One origin on the numpy reference."""
    sensor = context.active_sensor
    settings = GainSettings("prob", 0.0, sensor.min_range, sensor=context.returns_sensor, sampling=context.sampling,
                            surface=1.0)  # fmt: skip
    origin = np.asarray(cell, dtype=np.int64).reshape(1, -1)
    rays = ray_gains(state, prob, context.directions, sensor.r_max, origin, "numpy", settings=settings)[0]
    inside = np.asarray(context.membership)[:, view_index] != 0
    if not np.any(inside):
        return 0.0
    per_ray = view_solid_angle(sensor.hfov_deg, sensor.vfov_deg if state.ndim == 3 else None) / np.count_nonzero(inside)
    total_weight = distance_weights(sensor.r_max, state.ndim).sum()
    return float(rays[inside].astype(np.float64).sum() * per_ray * total_weight)


def view_solid_angle(hfov_deg: float, vfov_deg: float | None) -> float:
    """The angle of a view: ``hfov`` in radians (2D, ``vfov_deg`` None), else the solid angle of the
    rectangular frustum, ``4 asin(sin(h / 2) sin(v / 2))`` steradians."""
    h = math.radians(hfov_deg)
    if vfov_deg is None:
        return h
    return 4.0 * math.asin(math.sin(h / 2.0) * math.sin(math.radians(vfov_deg) / 2.0))


@dataclass(frozen=True)
class SurfaceStop:
    """Stop exploring once the best view's predicted new surface (:func:`predicted_new_surface`) is
    below ``cells``, or below ``share`` times the surface seen so far (the cells known occupied);
    the larger of the two thresholds holds. 0 disables a threshold.

    Raises:
        ValueError: a negative or non-finite threshold.
    """

    cells: float = 0.0
    share: float = 0.0

    def __post_init__(self) -> None:
        for name in ("cells", "share"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"stop_new_surface_{name}: expected a finite threshold >= 0, got {value!r}")

    @property
    def active(self) -> bool:
        return self.cells > 0 or self.share > 0

    def threshold(self, state: np.ndarray) -> float:
        """Cells below which a view's predicted new surface ends the exploration on ``state``."""
        seen = int(np.count_nonzero(np.asarray(state) == 1))
        return max(float(self.cells), float(self.share) * seen)

    def reason(self, state: np.ndarray, new_surface: float) -> str | None:
        """Why to stop before a view of ``new_surface`` predicted cells, or None to go on."""
        if not self.active:
            return None
        limit = self.threshold(state)
        if new_surface < limit:
            seen = int(np.count_nonzero(np.asarray(state) == 1))
            return (f"surface finished: the best view's predicted new surface {new_surface:.1f} cells < "
                    f"{limit:.1f} (stop_new_surface_cells {self.cells:g}, share {self.share:g} of the "
                    f"{seen} surface cells seen)")  # fmt: skip
        return None
