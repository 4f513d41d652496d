"""Candidate orientations and frustum membership (docs/method.md#candidate-views-and-view-gain)."""

import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import (
    in_frustum,
    matrix_from_quaternion,
    optical_axis,
    orientations,
    quaternion_from_matrix,
    view_directions_3d,
)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def test_orientation_counts():
    assert orientations(2).shape == (60,)
    np.testing.assert_allclose(np.diff(orientations(2)), math.radians(6))
    quats = orientations(3)
    assert quats.shape == (52, 4)
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0)
    axes = np.array([optical_axis(q, 3) for q in quats])
    # 26 distinct viewing directions, each with two rolls
    assert len({tuple(np.round(a, 6)) for a in axes}) == 26
    np.testing.assert_allclose(axes[0::2], view_directions_3d(), atol=1e-12)
    np.testing.assert_allclose(axes[1::2], view_directions_3d(), atol=1e-12)


def test_optical_frame_is_rep103():
    # looking along +x with roll 0: image right is -y, image down is -z
    q = orientations(3)[16]
    rot = matrix_from_quaternion(q)
    np.testing.assert_allclose(rot[:, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rot[:, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(rot[:, 1], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(quaternion_from_matrix(rot), q, atol=1e-12)


def test_frustum_edges_3d():
    forward_x_roll0, forward_x_roll90 = orientations(3)[16], orientations(3)[17]
    dirs = np.array(
        [
            _unit([1, math.tan(math.radians(29)), 0]),  # inside horizontally (HFOV/2 = 30)
            _unit([1, math.tan(math.radians(31)), 0]),  # outside horizontally
            _unit([1, 0, math.tan(math.radians(22))]),  # inside vertically (VFOV/2 = 23)
            _unit([1, 0, math.tan(math.radians(24))]),  # outside vertically
            _unit([-1, 0, 0]),  # behind
        ]
    )
    inside = in_frustum(dirs, np.array([forward_x_roll0, forward_x_roll90]), 60.0, 46.0)
    np.testing.assert_array_equal(inside[:, 0], [True, False, True, False, False])
    # rolled by 90 degrees the horizontal and vertical fields swap
    np.testing.assert_array_equal(inside[:, 1], [False, False, True, True, False])


def test_frustum_2d():
    dirs = np.array([_unit([1, math.tan(math.radians(a))]) for a in (0, 29, 31, -29)])
    inside = in_frustum(dirs, np.array([0.0, math.pi]), 60.0)
    np.testing.assert_array_equal(inside[:, 0], [True, True, False, True])
    assert not inside[:, 1].any()


def test_bad_quaternion():
    with pytest.raises(ValueError, match="quaternion"):
        matrix_from_quaternion([0, 0, 0, 0])
    with pytest.raises(ValueError, match="quaternion"):
        matrix_from_quaternion([np.nan, 0, 0, 1])
