"""Rays through a pose's own image (gain/frustum_rays.py) and the pose scores they give
(score_poses(rays_across=n)), against hand-worked values (issue 36)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor, look_rotation, quaternion_from_matrix
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.gain.frustum_rays import frustum_rays
from nbv_prob_cnn.planners import PlanningContext
from nbv_prob_cnn.planners.pose_scoring import VALID, score_poses


def frustum_solid_angle(hfov_deg: float, vfov_deg: float) -> float:
    """A pinhole pyramid's solid angle, 4 atan(a b / sqrt(1 + a^2 + b^2)) with a, b the half-angle tangents."""
    a, b = math.tan(math.radians(hfov_deg) / 2), math.tan(math.radians(vfov_deg) / 2)
    return 4 * math.atan(a * b / math.sqrt(1 + a * a + b * b))


def test_a_90_degree_square_image_of_two_by_two_rays():
    directions, weights = frustum_rays(3, 2, 90.0, 90.0)
    # the image plane z = 1 spans [-1, 1]^2: pixel centres (+-0.5, +-0.5), top row (y = -0.5) first
    expected = np.array([[-0.5, -0.5, 1], [0.5, -0.5, 1], [-0.5, 0.5, 1], [0.5, 0.5, 1]]) / math.sqrt(1.5)
    np.testing.assert_allclose(directions, expected, atol=1e-12)
    # a cube face is 4 pi / 6 sr; its four quarters are alike
    np.testing.assert_allclose(weights, np.full(4, math.pi / 6), atol=1e-12)


def test_the_weights_sum_to_the_frustum_and_the_rows_follow_the_aspect():
    directions, weights = frustum_rays(3, 32, 57.0, 45.0)
    # rows: round(32 tan(22.5 deg) / tan(28.5 deg)) = round(24.35) = 24
    assert directions.shape == (32 * 24, 3)
    assert weights.sum() == pytest.approx(frustum_solid_angle(57.0, 45.0), rel=1e-12)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    assert np.all(directions[:, 2] > 0)
    # the centre pixels stand for more solid angle than the corners (cos^3 of the off-axis angle)
    assert weights.max() == pytest.approx(weights.reshape(24, 32)[11:13, 15:17].max())
    assert weights.min() == pytest.approx(weights.reshape(24, 32)[0, 0])
    one, whole = frustum_rays(3, 1, 60.0, 46.0)
    np.testing.assert_allclose(one, [[0.0, 0.0, 1.0]])
    assert whole[0] == pytest.approx(frustum_solid_angle(60.0, 46.0))


def test_2d_rays_fan_across_the_field_of_view():
    directions, weights = frustum_rays(2, 2, 90.0)
    angle = math.radians(22.5)
    np.testing.assert_allclose(directions, [[math.cos(angle), -math.sin(angle)], [math.cos(angle), math.sin(angle)]])
    np.testing.assert_allclose(weights, [math.pi / 4, math.pi / 4])


@pytest.mark.parametrize(
    ("args", "match"),
    [((4, 8, 60.0, 46.0), "dims"), ((3, 0, 60.0, 46.0), "across"), ((3, 8, 180.0, 46.0), "hfov"),
     ((3, 8, 60.0, None), "vfov"), ((3, 8, 60.0, 0.0), "vfov")],
)  # fmt: skip
def test_bad_arguments_are_refused_by_name(args, match):
    with pytest.raises(ValueError, match=match):
        frustum_rays(*args)


SHAPE = (31, 31, 31)
CENTRE = np.array([15, 15, 15])
R_MAX = 9  # the rays end inside the grid (15 - 9 > 0)
SMALL = DatasetDefaults("3du", 3, SHAPE, 0.05, Sensor(60.0, 46.0, R_MAX), 4, 3)
P = 0.15


def ray_gain_by_hand() -> float:
    """G_r of a ray whose samples t = 1..9 are all unknown of probability P (t = 0 is the empty origin):
    H = sum t^2 (1 - P)^(t - 1), H + M = sum t^2."""
    t = np.arange(1, R_MAX + 1)
    return float(np.sum(t**2 * (1 - P) ** (t - 1)) / np.sum(t**2))


def pose(forward) -> tuple[np.ndarray, np.ndarray]:
    geometry = GridGeometry((0.0, 0.0, 0.0), SMALL.resolution_m, SHAPE)
    return geometry.cell_centre(CENTRE[None]), quaternion_from_matrix(look_rotation(np.asarray(forward, float)))[None]


def test_own_frustum_score_is_the_frustum_solid_angle_times_the_ray_gain():
    state = np.full(SHAPE, -1, dtype=np.int8)
    state[tuple(CENTRE)] = 0
    geometry = GridGeometry((0.0, 0.0, 0.0), SMALL.resolution_m, SHAPE)
    context = PlanningContext(SMALL, backend="numpy")
    expected = ray_gain_by_hand() * frustum_solid_angle(60.0, 46.0)
    for forward in ([1, 0, 0], [0, -1, 0], [1, 2, -3]):
        positions, quats = pose(forward)
        scores = score_poses(state, probability_with_constant(state, P), geometry, positions, quats, context,
                             rays_across=8)  # fmt: skip
        assert scores.validity[0] == VALID
        assert scores.gains[0] == pytest.approx(expected, rel=1e-5)


def test_own_frustum_rays_look_where_the_pose_looks():
    # known empty at x <= 15 (the camera's side), unknown beyond: looking +x sees only unknown samples, -x none
    state = np.full(SHAPE, -1, dtype=np.int8)
    state[:16] = 0
    geometry = GridGeometry((0.0, 0.0, 0.0), SMALL.resolution_m, SHAPE)
    prob = probability_with_constant(state, P)
    expected = ray_gain_by_hand() * frustum_solid_angle(60.0, 46.0)
    for backend in ("numpy", "auto"):
        context = PlanningContext(SMALL, backend=backend)
        forward, backward = pose([1, 0, 0]), pose([-1, 0, 0])
        positions, quats = np.vstack([forward[0], backward[0]]), np.vstack([forward[1], backward[1]])
        scores = score_poses(state, prob, geometry, positions, quats, context, rays_across=12)
        np.testing.assert_allclose(scores.gains, [expected, 0.0], rtol=1e-5, atol=1e-7)


def test_rays_across_must_be_a_count():
    state = np.zeros(SHAPE, dtype=np.int8)
    geometry = GridGeometry((0.0, 0.0, 0.0), SMALL.resolution_m, SHAPE)
    positions, quats = pose([1, 0, 0])
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="rays_across"):
            score_poses(state, None, geometry, positions, quats, PlanningContext(SMALL), "ig", rays_across=bad)
