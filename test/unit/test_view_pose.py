"""From (cell, view index) to a pose in metres and a quaternion, against hand-worked cases."""

import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.basics.view_pose import view_pose, view_quaternion
from nbv_prob_cnn.gain import best_origin_view, ray_directions, view_membership
from nbv_prob_cnn.planners import ViewChoice

H = math.sqrt(0.5)


def test_cell_to_metres_by_hand():
    # cell (10, 0, 3) of a grid with its cell-0 corner at (-0.5, 0.2, 0.0) and 2 cm cells:
    # centre = corner + (index + 0.5) * 0.02 = (-0.5 + 0.21, 0.2 + 0.01, 0.0 + 0.07)
    geometry = GridGeometry((-0.5, 0.2, 0.0), 0.02, (20, 20, 20))
    pose = view_pose((10, 0, 3), 0, geometry)
    np.testing.assert_allclose(pose.position_m, [-0.29, 0.21, 0.07], atol=1e-12)
    assert pose.cell == (10, 0, 3)


def test_2d_cell_keeps_the_origin_height():
    geometry = GridGeometry((1.0, 2.0, 0.5), 0.6, (50, 50))
    pose = view_pose(np.array([0, 4]), 15, geometry)  # yaw 15 * 6 deg = 90 deg
    np.testing.assert_allclose(pose.position_m, [1.3, 4.7, 0.5], atol=1e-12)
    np.testing.assert_allclose(pose.quaternion_xyzw, [0.0, 0.0, H, H], atol=1e-12)  # 90 deg about +z


def test_view_index_to_quaternion_by_hand():
    # view 48 = direction 24 (straight up), roll 0: forward +z, image up would be +z, so it is
    # +x; optical x = z × x = +y, optical y = z × (optical x) = -x: a rotation by +90 deg about z.
    np.testing.assert_allclose(view_quaternion(48, 3), [0.0, 0.0, H, H], atol=1e-9)
    # view 16 = direction 8 (horizontal, azimuth 0), roll 0: forward +x, optical x = -y,
    # optical y = -z: the usual "optical frame looking along +x", quaternion (-1/2, 1/2, -1/2, 1/2).
    np.testing.assert_allclose(view_quaternion(16, 3), [-0.5, 0.5, -0.5, 0.5], atol=1e-9)


def test_bad_cell_and_view_are_refused():
    geometry = GridGeometry((0.0, 0.0, 0.0), 0.1, (4, 4, 4))
    with pytest.raises(ValueError, match="outside the grid"):
        view_pose((4, 0, 0), 0, geometry)
    with pytest.raises(ValueError, match="3 integer indices"):
        view_pose((1.5, 0, 0), 0, geometry)
    with pytest.raises(ValueError, match="view_index"):
        view_pose((1, 1, 1), 52, geometry)


def test_best_origin_view_unpacks_and_carries_its_pose():
    # one empty cell at (2, 3) in an unknown 2D map: the only origin; every view has gain
    state = np.full((8, 8), -1, dtype=np.int8)
    state[2, 3] = 0
    dirs = ray_directions(2, 4)
    member = view_membership(dirs, np.deg2rad(np.arange(0, 360, 6.0)), 60.0)
    best = best_origin_view(state, probability_with_constant(state, 0.2), dirs, 4, member, backend="numpy")
    index, view, gain = best
    assert (index, best.cell) == (0, (2, 3)) and gain > 0
    pose = best.pose(GridGeometry((0.0, 0.0, 0.0), 0.5, state.shape))
    np.testing.assert_allclose(pose.position_m, [1.25, 1.75, 0.0])
    yaw = math.radians(6 * view)
    np.testing.assert_allclose(pose.quaternion_xyzw, [0, 0, math.sin(yaw / 2), math.cos(yaw / 2)], atol=1e-12)
    assert pose.gain == gain


def test_ranked_view_choice_has_a_pose():
    choice = ViewChoice(np.array([1, 2, 3]), 16, 0.7)
    pose = choice.pose(GridGeometry((0.0, 0.0, 1.0), 0.1, (5, 5, 5)))
    np.testing.assert_allclose(pose.position_m, [0.15, 0.25, 1.35])
    np.testing.assert_allclose(pose.quaternion_xyzw, [-0.5, 0.5, -0.5, 0.5], atol=1e-9)
