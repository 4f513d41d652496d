"""The surface a planned view is expected to add (planners/surface_stop.py): a hand-worked single
ray, and a wall whose cells inside the frustum are counted independently."""

from __future__ import annotations

import numpy as np

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
    # 32 rays across the 60 degree view, each t * (60 / 32) degrees of cells at distance t: on a flat
    # wall seen up to 30 degrees off axis the patch across a ray undercounts by at most 1 / cos 30 (13 %)
    assert 0.85 * count <= estimate <= 1.02 * count


def test_nothing_unknown_nothing_new_and_uncertain_walls_add_less():
    context = PlanningContext.for_dataset("2d")
    state, prob = _wall(1.0)
    cell = np.array([0, 50])
    state[41:, :] = 1  # a wall one cell thick before a known one
    certain = predicted_new_surface(state, prob, cell, 0, context)
    half = predicted_new_surface(state, _wall(0.5)[1], cell, 0, context)
    # p 0.5: a ray's return lands on its first wall cell with 0.5; a ray at up to 30 degrees crosses at
    # most one more cell of the thin wall (0.25, a little farther), then the known wall (nothing new)
    assert certain > 30 and 0.5 * certain < half < 0.8 * certain
    known = np.where(state == -1, 1, state).astype(np.int8)  # the wall seen: no unknown cell left
    assert predicted_new_surface(known, prob, cell, 0, context) == 0.0
    assert predicted_new_surface(state, np.zeros_like(prob), cell, 0, context) == 0.0  # believed empty: no surface
