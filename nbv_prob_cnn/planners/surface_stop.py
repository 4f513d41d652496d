"""When to stop looking: the surface a planned view is expected to add, in cells, and the stop rule
on it (docs/method.md#stopping-when-the-surface-is-finished).

The surface term of a ray (:attr:`~nbv_prob_cnn.gain.settings.GainSettings.surface` 1) is the
expected weight of the unknown cell where its return lands. A ray of solid angle ``Ω_r`` (radians in
2D) meets at distance ``t`` cells a patch of about ``Ω_r t^nu`` cells (``w_t = t^nu``: ``t`` in 2D,
``t²`` in 3D), so the view's expected new surface is about ``Σ_r Ω_r S_r Σ_t w_t`` cells. The rays are
not the view search's few (56 on 3DT: 2-6 in a view, each a quarter of the image) but
:data:`SURFACE_RAYS_ACROSS` across the view's own image, each weighted by its pixel's solid angle
(:func:`~nbv_prob_cnn.gain.frustum_rays.frustum_rays`), and they march the exact voxel traversal,
which no diagonal corner between two occupied cells lets through (the rounded samples of the search
do, into unknown space no camera reaches). An estimate still: a surface seen obliquely holds more
cells than the patch across the ray.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.gain import ray_gains
from nbv_prob_cnn.gain.frustum_rays import frustum_rays
from nbv_prob_cnn.gain.sampling import traversal_table
from nbv_prob_cnn.gain.settings import GainSettings
from nbv_prob_cnn.planners.image_rays import camera_rotation

#: Rays across the view's image for the estimate (as ``/nbv/evaluate_views``' default).
SURFACE_RAYS_ACROSS = 32


def predicted_new_surface(
    state: np.ndarray,
    prob: np.ndarray,
    cell: np.ndarray,
    view_index: int,
    context,
    rays_across: int = SURFACE_RAYS_ACROSS,
) -> float:
    """The expected number of surface cells, unknown now, that the view ``(cell, view_index)`` of
    ``context`` (a :class:`~nbv_prob_cnn.planners.base.PlanningContext`) sees: the module's estimate
    on the occupancy map ``prob`` (read in unknown cells), one origin on the numpy reference."""
    sensor = context.active_sensor
    dims = state.ndim
    settings = GainSettings("prob", 0.0, sensor.min_range, sensor=context.returns_sensor, sampling="exact",
                            surface=1.0)  # fmt: skip
    directions, solid_angles = frustum_rays(dims, rays_across, sensor.hfov_deg, sensor.vfov_deg if dims == 3 else None)
    directions = directions @ camera_rotation(context.orientations[view_index]).T
    origin = np.asarray(cell, dtype=np.int64).reshape(1, -1)
    rays = ray_gains(state, prob, directions, sensor.r_max, origin, "numpy", settings=settings)[0]
    # the exact traversal's weights are d^nu over the ray's own sum of d^nu: times that sum, each ray
    # gives the expected d^nu of where its return lands on unknown surface
    _, distance, counts = traversal_table(directions, sensor.r_max)
    inside = (np.arange(distance.shape[1])[None, :] < counts[:, None]) & (distance <= sensor.r_max)
    sums = np.where(inside, distance ** (dims - 1), 0.0).sum(axis=1)
    return float(np.sum(rays.astype(np.float64) * sums * solid_angles))


def best_new_surface(state: np.ndarray, prob: np.ndarray, origins: np.ndarray, context) -> float:
    """The most new surface, in cells, that any candidate view at ``origins`` is expected to add: the
    best view of the surface term alone (the exact search with blend 1 on ``prob``), then its
    :func:`predicted_new_surface`. 0 when no view sees unknown space. What the stop rule compares: the
    view a blend chose may be one chosen for unknown space, and promise no surface while others do."""
    from dataclasses import replace

    from nbv_prob_cnn.planners.base import search_views

    found = search_views(state, prob, origins, replace(context, surface_blend=1.0), "prob", 1, surface=True)
    if not found:
        return 0.0
    return predicted_new_surface(state, prob, found[0].cell, found[0].view_index, context)


@dataclass(frozen=True)
class SurfaceStop:
    """Stop exploring once the most new surface a view can add (:func:`best_new_surface`) is
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

    def threshold(self, seen: int) -> float:
        """Cells below which a view's predicted new surface ends the exploration, with ``seen``
        surface cells (known occupied) so far."""
        return max(float(self.cells), float(self.share) * seen)

    def reason(self, state: np.ndarray, new_surface: float) -> str | None:
        """Why to stop before a view of ``new_surface`` predicted cells, or None to go on."""
        if not self.active:
            return None
        seen = int(np.count_nonzero(np.asarray(state) == 1))
        limit = self.threshold(seen)
        if new_surface < limit:
            return (f"surface finished: the best view's predicted new surface {new_surface:.1f} cells < "
                    f"{limit:.1f} (stop_new_surface_cells {self.cells:g}, share {self.share:g} of the "
                    f"{seen} surface cells seen)")  # fmt: skip
        return None
