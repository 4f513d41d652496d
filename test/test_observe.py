"""Simulated observation (SPEC §2)."""

import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import Sensor, orientations
from nbv_prob_cnn.sensing.observe import camera_rays, observe

SENSOR_2D = Sensor(60.0, None, 30)
BACKENDS = ["numpy", "opencl"]
SENSOR_3D = Sensor(60.0, 46.0, 12)


def _box_distance(shape, position):
    """Distance from ``position`` to the nearest point of every cell (cells are unit boxes)."""
    idx = np.indices(shape).astype(float)
    gap = [np.maximum(np.abs(idx[a] - position[a]) - 0.5, 0.0) for a in range(len(shape))]
    return np.sqrt(sum(g**2 for g in gap))


def test_ray_density_half_cell_at_max_range():
    for dims, sensor in [(2, SENSOR_2D), (3, SENSOR_3D)]:
        rays = camera_rays(sensor, dims)
        forward = rays[:, 0] if dims == 2 else rays[:, 2]
        assert forward.min() > 0
        if dims == 2:
            angles = np.sort(np.arctan2(rays[:, 1], rays[:, 0]))
            assert np.max(np.diff(angles)) * sensor.r_max <= 0.5 + 1e-9
            assert angles[-1] == pytest.approx(math.radians(30))


@pytest.mark.parametrize("backend", BACKENDS)
def test_nothing_seen_behind_a_wall_2d(backend):
    truth = np.zeros((60, 60), dtype=np.uint8)
    truth[20, :] = 1
    state = np.full(truth.shape, -1, dtype=np.int8)
    observe(state, truth, np.array([10, 30]), 0.0, SENSOR_2D, backend)
    assert np.all(state[21:] == -1)
    seen_wall = np.flatnonzero(state[20] == 1)
    # the wall is hit across the whole field of view: |y - 30| <= 10 * tan(30 deg) ~ 5.8
    assert seen_wall.min() <= 25 and seen_wall.max() >= 35
    assert np.all(state[11:20][state[11:20] != -1] == 0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_nothing_seen_beyond_max_range_3d(backend):
    truth = np.zeros((40, 40, 40), dtype=np.uint8)
    state = np.full(truth.shape, -1, dtype=np.int8)
    position = np.array([5, 20, 20])
    observe(state, truth, position, orientations(3)[16], SENSOR_3D, backend)  # looking along +x
    dist = _box_distance(truth.shape, position)
    known = state != -1
    assert known.sum() > 500
    assert dist[known].max() <= SENSOR_3D.r_max + 1e-9
    assert dist[known].max() >= SENSOR_3D.r_max - 1.0  # and it does reach max range
    assert not known[:5].any()  # nothing behind the camera


@pytest.mark.parametrize("backend", BACKENDS)
def test_unknown_only_decreases_and_known_cells_match_truth(rng, backend):
    truth = (rng.random((30, 30, 30)) < 0.04).astype(np.uint8)
    truth[15, 15, 15] = 0
    state = np.full(truth.shape, -1, dtype=np.int8)
    previous = state.size
    quats = orientations(3)
    for i in range(6):
        newly = observe(state, truth, np.array([15, 15, 15]), quats[i * 8], SENSOR_3D, backend)
        unknown = int(np.count_nonzero(state == -1))
        assert unknown == previous - newly
        assert unknown <= previous
        previous = unknown
        known = state != -1
        np.testing.assert_array_equal(state[known], truth[known])
    assert previous < state.size


@pytest.mark.parametrize("backend", BACKENDS)
def test_observation_is_view_limited_2d(backend):
    truth = np.zeros((80, 80), dtype=np.uint8)
    state = np.full(truth.shape, -1, dtype=np.int8)
    observe(state, truth, np.array([40, 40]), math.pi / 2, SENSOR_2D, backend)  # looking along +y
    ys, xs = np.nonzero((state != -1).T)
    angles = np.degrees(np.arctan2(ys - 40.0, xs - 40.0))
    far = np.hypot(ys - 40.0, xs - 40.0) > 3
    assert np.all(np.abs(angles[far] - 90) <= 30 + 12)  # within the field of view (cell-size slack)


def test_bad_inputs():
    truth = np.zeros((10, 10), dtype=np.uint8)
    state = np.full((10, 10), -1, dtype=np.int8)
    with pytest.raises(ValueError, match="position"):
        observe(state, truth, np.array([np.nan, 2]), 0.0, SENSOR_2D)
    with pytest.raises(ValueError, match="position"):
        observe(state, truth, np.array([20, 2]), 0.0, SENSOR_2D)
    with pytest.raises(ValueError, match="ground_truth"):
        observe(state, np.zeros((9, 10), dtype=np.uint8), np.array([2, 2]), 0.0, SENSOR_2D)
    with pytest.raises(ValueError, match="state"):
        observe(state.astype(np.int16), truth, np.array([2, 2]), 0.0, SENSOR_2D)
    with pytest.raises(ValueError, match="orientation"):
        observe(state, truth, np.array([2, 2]), float("nan"), SENSOR_2D)


@pytest.mark.parametrize("shape,sensor", [((50, 40), SENSOR_2D), ((30, 26, 22), SENSOR_3D)])
def test_backends_mark_identical_cells(rng, shape, sensor):
    truth = (rng.random(shape) < 0.03).astype(np.uint8)
    free = np.argwhere(truth == 0)
    views = orientations(len(shape))
    total_seen = 0
    for _ in range(8):
        cell = free[rng.integers(free.shape[0])] + rng.uniform(-0.4, 0.4, len(shape))  # off-centre too
        orientation = views[rng.integers(views.shape[0])]
        a = np.full(shape, -1, dtype=np.int8)
        b = a.copy()
        observe(a, truth, cell, orientation, sensor, "numpy")
        observe(b, truth, cell, orientation, sensor, "opencl")
        total_seen += np.count_nonzero(a != -1)
        np.testing.assert_array_equal(a, b)
    assert total_seen > 400  # the views saw enough to make the comparison meaningful
