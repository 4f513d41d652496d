"""Simulated observation (docs/method.md#sensor-and-simulated-observation)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import Sensor, dataset_defaults, look_rotation, orientations, quaternion_from_matrix
from nbv_prob_cnn.sensing.observe import camera_rays, measure_rays, observe, wall_distance, world_rays
from nbv_prob_cnn.sensing.sensor_noise import SensorNoise, sensor_noise

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


# -- the noisy path: the same traversal, labelled from the measured depth ----------------------------

OFF = SensorNoise("off")  # every noise effect off (observe() itself would take the exact path for it)


def _measured_state(truth, cell, orientation, sensor, noise, backend, margin_cells=None, seed=0, resolution_m=1.0):
    """The labels of one view through measure_rays (the noisy path), merged into an unknown grid."""
    state = np.full(truth.shape, -1, dtype=np.int8)
    rays = world_rays(orientation, sensor, truth.ndim)
    empty, occupied = measure_rays(truth, np.asarray(cell, float), rays, noise, np.random.default_rng(seed),
                                   resolution_m, margin_cells, backend)  # fmt: skip
    state.reshape(-1)[empty] = 0
    state.reshape(-1)[occupied] = 1
    return state


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("walls", [False, True])
@pytest.mark.parametrize("shape", [(50, 40), (30, 26, 22)])
def test_noise_free_measurement_labels_exactly_the_exact_cells(rng, backend, walls, shape):
    """Every ray returns (a closed box, or the room's walls): the noisy path with every effect off
    labels the cells of the exact observation, cell for cell."""
    truth = (rng.random(shape) < 0.03).astype(np.uint8)
    if not walls:  # a closed box: the grid's outer layer is occupied
        border = np.ones(shape, dtype=bool)
        border[tuple(slice(1, -1) for _ in shape)] = False
        truth[border] = 1
    # R_max beyond the grid's diagonal: the exact observation is bounded by the grid alone
    sensor = Sensor(60.0, None if len(shape) == 2 else 46.0, int(math.ceil(math.hypot(*shape))) + 2)
    free = np.argwhere(truth == 0)
    views = orientations(len(shape))
    seen = 0
    for _ in range(6):
        cell = free[rng.integers(free.shape[0])]
        orientation = views[rng.integers(views.shape[0])]
        exact = np.full(shape, -1, dtype=np.int8)
        observe(exact, truth, cell, orientation, sensor, backend)
        measured = _measured_state(truth, cell, orientation, sensor, OFF, backend, 5.0 if walls else None)
        np.testing.assert_array_equal(measured, exact)
        seen += np.count_nonzero(exact != -1)
    assert seen > 1000


def test_noisy_backends_label_identical_cells(rng):
    """The OpenCL kernels repeat the numpy reference (same traversal, same drawn noise)."""
    shape = (40, 36, 30)
    truth = (rng.random(shape) < 0.02).astype(np.uint8)
    sensor = Sensor(60.0, 46.0, 16)
    free = np.argwhere(truth == 0)
    views = orientations(3)
    # cm-level noise on 2 cm cells: measured ends move across cells, also behind the surfaces
    noisy = replace(sensor_noise("kinect_v1"), axial_a=0.02, axial_b=0.01, min_range_m=0.1)
    seen = 0
    for seed in range(5):
        cell = free[rng.integers(free.shape[0])]
        orientation = views[rng.integers(views.shape[0])]
        a = _measured_state(truth, cell, orientation, sensor, noisy, "numpy", 8.0, seed, 0.02)
        b = _measured_state(truth, cell, orientation, sensor, noisy, "opencl", 8.0, seed, 0.02)
        seen += np.count_nonzero(a != -1)
        np.testing.assert_array_equal(a, b)
    assert seen > 3000


def test_view_along_the_diagonal_adds_nearly_all_exact_depth_cells():
    """A Kinect view along a 3DT grid's diagonal (rays longer than the planner's R_max, most of
    them leaving the grid for the room's walls) labels >= 95 % of the cells its exact depths
    label, and more than the exact observation within R_max."""
    defaults = dataset_defaults("3dt")
    shape, resolution = defaults.shape, defaults.resolution_m
    truth = np.zeros(shape, dtype=np.uint8)
    truth[60:70, 60:70, 40:56] = 1  # a box in the middle of the view
    cell = np.array([3, 3, 3])
    quat = quaternion_from_matrix(look_rotation(np.array(shape, dtype=float) - 1 - cell))
    margin = 0.3 / resolution
    kinect = sensor_noise("kinect_v1")
    # the exact depths through the OpenCL kernels: the numpy reference labels the same cells
    # (test_noise_free_measurement_labels_exactly_the_exact_cells, test_noisy_backends_label_identical_cells)
    # but takes ~15 s to trace this view's 65k rays across the grid to the walls
    exact_depth = _measured_state(
        truth, cell, quat, defaults.sensor, replace(OFF, max_range_m=4.0), "opencl", margin, resolution_m=resolution
    )
    noisy = np.full(shape, -1, dtype=np.int8)
    observe(noisy, truth, cell, quat, defaults.sensor, noise=kinect, rng=np.random.default_rng(3),
            resolution_m=resolution, room_margin_m=0.3)  # fmt: skip
    within_r_max = np.full(shape, -1, dtype=np.int8)
    observe(within_r_max, truth, cell, quat, defaults.sensor)
    n_exact = np.count_nonzero(exact_depth != -1)
    assert np.count_nonzero(noisy != -1) >= 0.95 * n_exact
    assert n_exact > 1.5 * np.count_nonzero(within_r_max != -1)  # the diagonal is ~205 cells, R_max 128
    # every cell the noisy view labels empty is empty in the ground truth but for the surface cells
    assert np.count_nonzero((noisy == 0) & (truth == 1)) <= 0.01 * np.count_nonzero(noisy == 0)


def test_wall_distance_by_hand():
    # a 10 x 10 grid spans -0.5 .. 9.5; walls 2 cells out: x = 11.5, y = -2.5 ...
    rays = np.array([[1.0, 0.0], [0.0, -1.0], [math.sqrt(0.5), math.sqrt(0.5)], [0.6, 0.8]])
    t, cos = wall_distance((10, 10), np.array([4.0, 4.0]), rays, 2.0)
    # +x: 7.5; -y: 6.5; diagonal: x and y walls both at 7.5 -> 7.5 / sqrt(0.5); (0.6, 0.8): y wall at 7.5 / 0.8
    np.testing.assert_allclose(t, [7.5, 6.5, 7.5 / math.sqrt(0.5), 7.5 / 0.8])
    np.testing.assert_allclose(cos, [1.0, 1.0, math.sqrt(0.5), 0.8])
