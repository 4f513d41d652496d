"""The surface a planned view is expected to add (planners/surface_stop.py): a hand-worked single
ray, and a wall whose cells inside the frustum are counted independently."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import in_frustum
from nbv_prob_cnn.planners import PlanningContext
from nbv_prob_cnn.planners.surface_stop import predicted_new_surface


def _wall(p_wall: float) -> tuple[np.ndarray, np.ndarray]:
    """A 2D room, empty but for a wall of unknown cells at x = 40 (probability ``p_wall``)."""
    state = np.zeros((60, 101), dtype=np.int8)
    prob = np.zeros(state.shape, dtype=np.float32)
    state[40:, :] = -1
    prob[40:, :] = p_wall
    return state, prob


def test_a_certain_wall_is_about_the_cells_inside_the_frustum():
    context = PlanningContext.for_dataset("2d")
    state, prob = _wall(1.0)
    cell = np.array([0, 50])
    view = 0  # yaw 0: looking along +x at the wall, 40 cells away
    estimate = predicted_new_surface(state, prob, cell, view, context)
    # independent count: the wall cells (x = 40) whose centre direction lies inside the 60 degree view
    ys = np.arange(101)
    directions = np.stack([np.full(101, 40.0), ys - 50.0], axis=1)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    inside = in_frustum(directions, np.array([0.0]), context.active_sensor.hfov_deg, None)[:, 0]
    count = int(np.count_nonzero(inside))
    assert count == 47
    # the estimate counts t * (60 degrees / 8 rays) cells per ray at distance t: on a flat wall seen
    # up to 30 degrees off axis it undercounts by at most 1 / cos 30 (13 %)
    assert 0.85 * count <= estimate <= 1.05 * count


def test_by_hand_one_ray_set():
    context = PlanningContext.for_dataset("2d")
    state, prob = _wall(0.5)
    cell = np.array([0, 50])
    member = np.asarray(context.membership)[:, 0] != 0
    # each ray in the view meets the wall at its first sample with x >= 40: t = ceil-ish of 40 / cos;
    # with p 0.5 the return lands there with probability 0.5, and later samples are reached with
    # 0.5, 0.25, ... (every sample after it on the wall is unknown too, weight t each)
    expected = 0.0
    r_max = context.active_sensor.r_max
    for b in context.directions[member]:
        visible = 1.0
        for t in range(r_max + 1):
            x, y = int(np.rint(t * b[0])), int(np.rint(50 + t * b[1]))
            if not (0 <= x < 60 and 0 <= y < 101):
                break  # outside the grid: occupied, known, no new surface
            if state[x, y] == -1:
                expected += visible * 0.5 * t
                visible *= 0.5
    expected *= math.radians(60.0) / np.count_nonzero(member)
    assert predicted_new_surface(state, prob, cell, 0, context) == pytest.approx(expected, rel=1e-5)


def test_view_solid_angle_by_hand():
    from nbv_prob_cnn.planners.surface_stop import view_solid_angle

    assert view_solid_angle(60.0, None) == pytest.approx(math.pi / 3)
    # a 90 x 90 degree frustum is one face of a cube: 4 pi / 6 steradians
    assert view_solid_angle(90.0, 90.0) == pytest.approx(4 * math.pi / 6)
