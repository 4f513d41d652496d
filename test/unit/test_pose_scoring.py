"""Scoring arbitrary camera poses against the candidate-view search."""

import numpy as np

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.planners import PlanningContext
from nbv_prob_cnn.planners.base import search_views
from nbv_prob_cnn.planners.pose_scoring import (
    IN_OCCUPIED_CELL,
    IN_UNKNOWN_CELL,
    INVALID_POSE,
    OUTSIDE_GRID,
    VALID,
    score_poses,
)

SMALL_3D = DatasetDefaults("3du", 3, (20, 18, 16), 0.05, Sensor(60.0, 46.0, 9), 4, 3)
SMALL_2D = DatasetDefaults("2d", 2, (40, 36), 0.5, Sensor(60.0, None, 15), 16, 6)


def _grid(rng, shape):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=shape, p=[0.5, 0.45, 0.05])
    return state, probability_with_constant(state, 0.15)


def test_candidate_poses_score_like_the_view_search(rng):
    for defaults in (SMALL_3D, SMALL_2D):
        state, prob = _grid(rng, defaults.shape)
        geometry = GridGeometry((1.0, -2.0, 0.5), defaults.resolution_m, defaults.shape)
        context = PlanningContext(defaults)
        ranked = search_views(state, prob, np.argwhere(state == 0), context, top_k=30)
        positions = geometry.cell_centre(np.array([r.cell for r in ranked]))
        # jitter inside the cell: the camera is still scored from that cell
        positions[:, : defaults.dims] += rng.uniform(-0.45, 0.45, (len(ranked), defaults.dims)) * geometry.resolution
        if defaults.dims == 2:
            yaws = context.orientations[[r.view_index for r in ranked]]
            quats = np.stack([np.zeros_like(yaws), np.zeros_like(yaws), np.sin(yaws / 2), np.cos(yaws / 2)], axis=1)
        else:
            quats = context.orientations[[r.view_index for r in ranked]] * -1.0  # q and -q: same rotation
        scores = score_poses(state, prob, geometry, positions, quats, context)
        assert np.all(scores.validity == VALID)
        np.testing.assert_allclose(scores.gains, [r.gain for r in ranked], rtol=1e-5)


def test_invalid_poses_get_reasons(rng):
    state, prob = _grid(rng, SMALL_3D.shape)
    state[0, 0, 0], state[1, 0, 0], state[2, 0, 0] = 1, -1, 0
    geometry = GridGeometry((0.0, 0.0, 0.0), SMALL_3D.resolution_m, SMALL_3D.shape)
    context = PlanningContext(SMALL_3D)
    centre = geometry.cell_centre(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]]))
    positions = np.vstack([centre, [[np.nan, 0, 0], [0.01, 0.01, 0.01], [-1.0, 0.0, 0.0]]])
    quats = np.array([[0, 0, 0, 1]] * 4 + [[0, 0, 0, 0], [0, 0, 0, 1]], dtype=float)
    scores = score_poses(state, prob, geometry, positions, quats, context)
    np.testing.assert_array_equal(
        scores.validity, [IN_OCCUPIED_CELL, IN_UNKNOWN_CELL, VALID, INVALID_POSE, INVALID_POSE, OUTSIDE_GRID]
    )
    assert scores.gains[[0, 1, 3, 4, 5]].sum() == 0
    assert "occupied" in scores.reasons[0] and scores.reasons[2] == "" and "outside" in scores.reasons[5]


def test_huge_and_tiny_finite_quaternions_are_scored_like_their_unit_quaternion(rng):
    """(1e200, 0, 0, 1e200) overflows a plain norm; it is the rotation of (1, 0, 0, 1) / sqrt(2). Every
    other pose of the request is scored whatever one pose holds."""
    state, prob = _grid(rng, SMALL_3D.shape)
    state[5, 5, 5] = 0
    geometry = GridGeometry((0.0, 0.0, 0.0), SMALL_3D.resolution_m, SMALL_3D.shape)
    context = PlanningContext(SMALL_3D)
    position = geometry.cell_centre(np.array([[5, 5, 5]]))[0]
    unit = np.array([1.0, 0.0, 0.0, 1.0]) / np.sqrt(2.0)
    quats = np.array([unit, [1e200, 0, 0, 1e200], [1e-200, 0, 0, 1e-200], [np.inf, 0, 0, 1], [0, 0, 0, 0]])
    scores = score_poses(state, prob, geometry, np.tile(position, (5, 1)), quats, context)
    np.testing.assert_array_equal(scores.validity, [VALID, VALID, INVALID_POSE, INVALID_POSE, INVALID_POSE])
    assert scores.gains[0] > 0
    assert scores.gains[1] == scores.gains[0]
    assert scores.gains[2:].sum() == 0


def test_unit_quaternions_against_hand_values():
    from nbv_prob_cnn.basics.camera import matrix_from_quaternion, unit_quaternions

    unit, ok = unit_quaternions(np.array([[0, 0, 3e300, 4e300], [0, 0, 0, 2], [np.nan, 0, 0, 1], [0, 0, 0, 0]]))
    np.testing.assert_array_equal(ok, [True, True, False, False])
    np.testing.assert_allclose(unit[:2], [[0, 0, 0.6, 0.8], [0, 0, 0, 1]])
    np.testing.assert_array_equal(unit[2:], 0.0)
    # a rotation of 2*atan2(0.6, 0.8) ~ 73.74 deg about z, from the huge finite components
    angle = 2 * np.arctan2(0.6, 0.8)
    expected = [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    np.testing.assert_allclose(matrix_from_quaternion(np.array([0, 0, 3e300, 4e300])), expected, atol=1e-12)
