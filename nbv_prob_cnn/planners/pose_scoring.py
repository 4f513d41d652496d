"""Score arbitrary camera poses (e.g. the poses a manipulator can reach) with the gain of
docs/method.md: gain, candidate views: the ray gains of the cell that contains the camera, summed over the rays inside
that pose's frustum: the view search's rays, or rays through the pose's own image
(:mod:`~nbv_prob_cnn.gain.frustum_rays`, docs/method.md#scoring-given-poses)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.basics.camera import in_frustum, unit_quaternions
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.gain import GainSettings, ray_gains
from nbv_prob_cnn.planners.base import PlanningContext
from nbv_prob_cnn.planners.image_rays import IMAGE_RAYS_ACROSS, image_ray_gains

VALID = 0
OUTSIDE_GRID = 1
IN_OCCUPIED_CELL = 2
IN_UNKNOWN_CELL = 3
INVALID_POSE = 4
#: Rays across a pose's own image that ``/nbv/evaluate_views`` scores with by default
#: (``gain_server``'s ``evaluate_rays_across``): :data:`~nbv_prob_cnn.planners.image_rays.IMAGE_RAYS_ACROSS`.
EVALUATE_RAYS_ACROSS = IMAGE_RAYS_ACROSS

REASONS = {
    VALID: "",
    OUTSIDE_GRID: "camera position outside the grid",
    IN_OCCUPIED_CELL: "camera position inside an occupied cell",
    IN_UNKNOWN_CELL: "camera position inside an unknown cell",
    INVALID_POSE: "NaN/infinite position or a zero/non-finite quaternion",
}


@dataclass
class PoseScores:
    """Per pose: view gain (0 when invalid), validity code and a human-readable reason."""

    gains: np.ndarray
    validity: np.ndarray
    reasons: list[str]


def yaw_of(quat: np.ndarray) -> float:
    """Heading of the camera's +x axis in the plane (2D grids), from a quaternion (x, y, z, w)."""
    x, y, z, w = quat
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def classify_poses(
    state: np.ndarray, geometry: GridGeometry, positions: np.ndarray, quats: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Validity code and containing cell of each pose (cells are meaningless where invalid)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    quats = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
    n = positions.shape[0]
    validity = np.full(n, VALID, dtype=np.uint8)
    _, quat_ok = unit_quaternions(quats, tiny=1e-6)
    validity[~np.all(np.isfinite(positions), axis=1) | ~quat_ok] = INVALID_POSE
    safe_positions = np.where(np.isfinite(positions), positions, 0.0)
    cells, inside = geometry.containing_cell(safe_positions)
    validity[(validity == VALID) & ~inside] = OUTSIDE_GRID
    ok = validity == VALID
    values = np.full(n, 0, dtype=np.int8)
    values[ok] = state[tuple(cells[ok].T)]
    validity[ok & (values == 1)] = IN_OCCUPIED_CELL
    validity[ok & (values == -1)] = IN_UNKNOWN_CELL
    return validity, cells


def score_poses(
    state: np.ndarray,
    prob: np.ndarray | None,
    geometry: GridGeometry,
    positions: np.ndarray,
    quats: np.ndarray,
    context: PlanningContext,
    mode: str = "prob",
    score_unknown_cells: bool = False,
    rays_across: int = 0,
    surface: bool = False,
) -> PoseScores:
    """Gain of each camera pose (position in metres, optical-frame quaternion x, y, z, w).

    The camera is placed at the centre of the cell containing it (the method's candidate
    origins are cell centres); its frustum comes from the pose's own orientation and the
    context's sensor (fields of view, range). With ``score_unknown_cells`` a pose in an unknown
    cell is scored like one in an empty cell (for a caller that checks collisions itself) and
    reported valid, its reason saying so.

    ``rays_across`` 0: the context's rays (those of the view search, so a candidate view's pose
    scores its search gain); ``n > 0``: ``n`` rays across the pose's own image
    (:func:`~nbv_prob_cnn.gain.frustum_rays.frustum_rays`), the gain ``Σ Ω_r G_r`` in steradians
    (radians in 2D). ``surface``: the surface gain of a surface method (``context.surface_blend``).
    """
    if not isinstance(rays_across, (int, np.integer)) or isinstance(rays_across, bool) or rays_across < 0:
        raise ValueError(f"rays_across: expected 0 (the context's rays) or a positive count, got {rays_across!r}")
    validity, cells = classify_poses(state, geometry, positions, quats)
    reasons = [REASONS[int(v)] for v in validity]
    if score_unknown_cells:
        for i in np.flatnonzero(validity == IN_UNKNOWN_CELL):
            reasons[i] = f"{REASONS[IN_UNKNOWN_CELL]} (scored: score_unknown_cells)"
        validity[validity == IN_UNKNOWN_CELL] = VALID
    gains = np.zeros(validity.shape[0], dtype=np.float32)
    ok = np.flatnonzero(validity == VALID)
    if not ok.size:
        return PoseScores(gains, validity, reasons)
    sensor = context.active_sensor
    settings = GainSettings(mode, context.eps, sensor.min_range, sensor=context.returns_sensor,
                            sampling=context.sampling, surface=context.surface_blend if surface else 0.0)  # fmt: skip
    q = unit_quaternions(quats, tiny=1e-6)[0][ok]
    orientations = np.array([yaw_of(v) for v in q]) if state.ndim == 2 else q
    if rays_across:
        gains[ok] = image_ray_gains(state, prob, cells[ok], orientations, context, settings, rays_across)
        return PoseScores(gains, validity, reasons)
    unique_cells, which = np.unique(cells[ok], axis=0, return_inverse=True)
    per_ray = ray_gains(state, prob, context.directions, sensor.r_max, unique_cells, context.backend,
                        settings=settings)  # fmt: skip
    member = in_frustum(context.directions, orientations, sensor.hfov_deg, sensor.vfov_deg)  # (R, P)
    gains[ok] = np.einsum("pr,rp->p", per_ray[which.reshape(-1)], member.astype(np.float32))
    return PoseScores(gains, validity, reasons)
