"""Gains of given views over rays through each view's own image, and the re-ranking of a view
search's best views by them (docs/method.md#re-ranking-by-the-image-rays).

The view search casts one fixed set of rays from every origin and sums those inside each candidate
frustum: with the 3D default (56 rays) a view holds 2 to 6 of them, so one ray that slips past a
surface can decide the search. A view's own image rays (:func:`~nbv_prob_cnn.gain.frustum_rays.frustum_rays`,
``across`` columns) cover its whole frustum. Casting them for every candidate would cost hundreds of
times the search; for the few best views of the search it costs a fraction of it.
"""

from __future__ import annotations

import math
import time

import numpy as np

from nbv_prob_cnn.basics.camera import matrix_from_quaternion
from nbv_prob_cnn.gain import GainSettings, each_origin_ray_gains
from nbv_prob_cnn.gain.frustum_rays import frustum_rays
from nbv_prob_cnn.planners.base import PlanningContext, ViewChoice
from nbv_prob_cnn.planners.candidates import crop_to_reach

#: Rays across each view's own image (``/nbv/evaluate_views``' default, the re-ranking's): on the
#: 7-Scenes kitchen (``nbv gain-study``, docs/evaluation.md#does-the-gain-predict-what-a-real-camera-sees)
#: the within-anchor rank agreement with what each frame revealed rose from 0.14 (prob_ig) / 0.29
#: (cnn_prob) with the view search's rays to 0.71 / 0.65 with 32; 64 gave no more.
IMAGE_RAYS_ACROSS = 32


def camera_rotation(orientation: np.ndarray | float) -> np.ndarray:
    """Grid-from-camera rotation of a pose: a yaw (2D, ``(2, 2)``) or a quaternion (3D, ``(3, 3)``)."""
    if np.ndim(orientation) == 0:
        c, s = math.cos(float(orientation)), math.sin(float(orientation))
        return np.array([[c, -s], [s, c]])
    return matrix_from_quaternion(np.asarray(orientation))


def image_ray_gains(
    state: np.ndarray,
    prob: np.ndarray | None,
    cells: np.ndarray,
    orientations: np.ndarray,
    context: PlanningContext,
    settings: GainSettings,
    across: int = IMAGE_RAYS_ACROSS,
    reach: np.ndarray | None = None,
) -> np.ndarray:
    """``Σ Ω_r G_r`` of each view (camera in ``cells``, ``(P, dims)``; ``orientations``: yaws in 2D,
    quaternions ``(x, y, z, w)`` of the optical frame in 3D) over ``across`` rays through its own
    image, each weighted by its solid angle (steradians; radians in 2D). Float64 ``(P,)``.

    One cast on the grid cut to the views' reach, each view's camera cell marching its own rays
    (:func:`~nbv_prob_cnn.gain.each_origin_ray_gains`): the grid is encoded and uploaded once (a
    cast per view cost about 35 ms of set-up a view on 3DT). ``reach``: cut it to the reach of these
    cells instead (``(M, dims)``, among them ``cells``; e.g. the view search's origins: the cast then
    marches the search's grid again, which the ray caster keeps)."""
    sensor = context.active_sensor
    camera_directions, weights = frustum_rays(state.ndim, across, sensor.hfov_deg, sensor.vfov_deg)
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, state.ndim)
    if cells.shape[0] == 0:
        return np.zeros(0, dtype=np.float64)
    directions = np.stack([camera_directions @ camera_rotation(o).T for o in orientations])
    cut_state, cut_prob, cut_cells, _ = crop_to_reach(state, prob, cells, sensor.r_max)
    per_ray = each_origin_ray_gains(cut_state, cut_prob, directions, sensor.r_max, cut_cells, context.backend,
                                    settings=settings)  # fmt: skip
    return per_ray.astype(np.float64) @ weights


def rerank_by_image(
    state: np.ndarray,
    prob: np.ndarray | None,
    found: list[ViewChoice],
    context: PlanningContext,
    settings: GainSettings,
    across: int = IMAGE_RAYS_ACROSS,
    reach: np.ndarray | None = None,
) -> list[ViewChoice]:
    """``found`` (a view search's best views) ordered by :func:`image_ray_gains`, best first (ties
    keep the search's order); views whose image rays gain nothing are dropped. Each keeps its search
    gain ``gain``; its ``image_gain`` is set, and the seconds spent are added to its ``raycast`` time.
    ``reach``: the search's origins (:func:`image_ray_gains`)."""
    if not found:
        return found
    start = time.perf_counter()
    cells = np.array([np.asarray(choice.cell).reshape(-1) for choice in found])
    orientations = context.orientations[[choice.view_index for choice in found]]
    gains = image_ray_gains(state, prob, cells, orientations, context, settings, across, reach)
    seconds = time.perf_counter() - start
    for choice, gain in zip(found, gains.tolist(), strict=True):
        choice.image_gain = gain
        choice.times["raycast"] = choice.times.get("raycast", 0.0) + seconds
    order = np.argsort(-gains, kind="stable")
    return [found[i] for i in order if gains[i] > 0.0]
