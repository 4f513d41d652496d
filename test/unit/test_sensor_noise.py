"""The depth-sensor noise models (nbv_prob_cnn.sensing.sensor_noise), on images and in grid-level observe()."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import dataset_defaults, look_rotation, quaternion_from_matrix
from nbv_prob_cnn.sensing.observe import observe
from nbv_prob_cnn.sensing.sensor_noise import PRESETS, SensorNoise, sensor_noise


def test_presets_and_bad_parameters():
    assert set(PRESETS) == {"ideal", "kinect_v1", "astra"} and sensor_noise("ideal").is_ideal
    assert not sensor_noise("kinect_v1").is_ideal
    with pytest.raises(ValueError, match="expected one of"):
        sensor_noise("kinect_v3")
    for bad in ({"axial_a": -1.0}, {"dropout": 1.5}, {"min_range_m": 2.0, "max_range_m": 1.0}, {"grazing_deg": 0.0}):
        with pytest.raises(ValueError, match="noise"):
            SensorNoise(**bad)


def test_ideal_changes_nothing_and_presets_are_seedable():
    depth = (1.0 + 0.01 * np.add.outer(np.arange(48), np.arange(64))).astype(np.float32)  # a smooth slope
    depth[5, 5] = 0.0
    assert np.array_equal(sensor_noise("ideal").apply_image(depth, np.random.default_rng(1)), depth)
    kinect = sensor_noise("kinect_v1")
    a = kinect.apply_image(depth, np.random.default_rng(7))
    b = kinect.apply_image(depth, np.random.default_rng(7))
    c = kinect.apply_image(depth, np.random.default_rng(8))
    assert np.array_equal(a, b) and not np.array_equal(a, c) and a[5, 5] == 0.0
    assert 0.9 < np.mean(a > 0) < 1.0


def test_axial_noise_follows_the_quadratic_model():
    kinect = replace(sensor_noise("kinect_v1"), dropout=0.0)
    z = np.full(200_000, 2.0)
    noisy = kinect.perturb_ranges(z, np.random.default_rng(3))
    expected = 0.0012 + 0.0019 * (2.0 - 0.4) ** 2  # 6.06 mm, by hand
    assert noisy.std() == pytest.approx(expected, rel=0.02) and noisy.mean() == pytest.approx(2.0, abs=1e-4)


def test_missing_depth_beyond_range_at_grazing_angles_and_at_edges():
    kinect = replace(sensor_noise("kinect_v1"), dropout=0.0, axial_a=0.0, axial_b=0.0, lateral_px=0.0)
    ranges = kinect.perturb_ranges(np.array([0.3, 1.0, 3.9, 4.5, np.nan]), np.random.default_rng(0))
    assert ranges.tolist() == [0.0, 1.0, 3.9, 0.0, 0.0]
    cos = np.cos(np.radians([0.0, 60.0, 74.0, 76.0, 89.0]))
    grazing = kinect.perturb_ranges(np.full(5, 1.0), np.random.default_rng(0), cos)
    assert grazing.tolist() == [1.0, 1.0, 1.0, 0.0, 0.0]  # the preset's limit is 75 degrees
    step = np.full((10, 20), 1.0)
    step[:, 10:] = 2.0  # a 1 m depth edge between columns 9 and 10
    image = kinect.apply_image(step, np.random.default_rng(0))
    assert np.all(image[:, 8:12] == 0) and np.all(image[:, :8] == 1.0) and np.all(image[:, 12:] == 2.0)


WALL_SHAPE = (64, 64, 64)


def _wall(z: int) -> np.ndarray:
    truth = np.zeros(WALL_SHAPE, np.uint8)
    truth[:, :, z:] = 1
    return truth


def _look_up_at(truth, noise, seed=0, resolution_m=0.05):
    state = np.full(WALL_SHAPE, -1, np.int8)
    quat = quaternion_from_matrix(look_rotation(np.array([0.0, 0.0, 1.0])))
    sensor = dataset_defaults("3du").sensor
    observe(state, truth, np.array([32.0, 32.0, 5.0]), quat, sensor, backend="numpy", noise=noise,
            rng=np.random.default_rng(seed), resolution_m=resolution_m)  # fmt: skip
    return state


def test_grid_observation_uses_the_same_model():
    truth = _wall(20)  # 15 cells = 0.75 m in front of the camera
    plain = np.full(WALL_SHAPE, -1, np.int8)
    sensor = dataset_defaults("3du").sensor
    quat = quaternion_from_matrix(look_rotation(np.array([0.0, 0.0, 1.0])))
    observe(plain, truth, np.array([32.0, 32.0, 5.0]), quat, sensor, backend="numpy")
    assert np.array_equal(_look_up_at(truth, sensor_noise("ideal")), plain)  # ideal = exact observation

    noisy = _look_up_at(truth, sensor_noise("kinect_v1"))
    assert np.array_equal(noisy, _look_up_at(truth, sensor_noise("kinect_v1")))  # seeded
    surface = np.argwhere(noisy == 1)
    assert len(surface) > 100 and np.all(np.abs(surface[:, 2] - 20) <= 2)  # mm-level noise: within 2 cells
    assert np.all(noisy[:, :, 21:] == -1)  # nothing behind the surface is seen
    # the same wall 0.4 m away is inside the Kinect's minimum range: no return, nothing labelled
    assert np.all(_look_up_at(_wall(13), sensor_noise("kinect_v1")) == -1)
    with pytest.raises(ValueError, match="needs rng"):
        observe(np.full(WALL_SHAPE, -1, np.int8), truth, np.array([32.0, 32.0, 5.0]), quat, sensor,
                noise=sensor_noise("astra"))  # fmt: skip


def test_depth_camera_takes_the_same_model():
    pytest.importorskip("open3d")
    trimesh = pytest.importorskip("trimesh")
    from nbv_prob_cnn.perception import DepthCamera, Intrinsics

    floor = trimesh.creation.box(extents=(20.0, 20.0, 0.01))
    intrinsics = Intrinsics.from_hfov(64, 48, 90.0)
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(np.array([0.0, 1.0, -0.35]))  # a glancing look over a floor 1 m below
    pose[:3, 3] = [0.0, 0.0, 1.0]
    exact = DepthCamera([floor], intrinsics).render(pose)
    noisy = DepthCamera([floor], intrinsics, noise=sensor_noise("kinect_v1"), noise_seed=4).render(pose)
    again = DepthCamera([floor], intrinsics, noise=sensor_noise("kinect_v1"), noise_seed=4).render(pose)
    assert np.array_equal(noisy, again)
    far_or_grazing = (exact > 4.0) | (exact == 0)
    assert far_or_grazing.any() and np.all(noisy[far_or_grazing] == 0)
    seen = (noisy > 0) & (exact > 0)
    # lateral noise borrows depths of neighbouring rows (steep on a glancing floor): a few % off
    assert seen.sum() > 100 and np.median(np.abs(noisy[seen] - exact[seen]) / exact[seen]) < 0.05
    ideal = DepthCamera([floor], intrinsics, noise=sensor_noise("ideal")).render(pose)
    assert np.array_equal(ideal, exact)


def test_walls_outside_the_grid_give_returns_to_rays_that_leave_it():
    empty_world = np.zeros(WALL_SHAPE, np.uint8)  # no surface inside the grid
    kinect = sensor_noise("kinect_v1")
    assert np.all(_look_up_at(empty_world, kinect) == -1)  # no wall: no return, nothing known
    state = np.full(WALL_SHAPE, -1, np.int8)
    quat = quaternion_from_matrix(look_rotation(np.array([0.0, 0.0, 1.0])))
    sensor = dataset_defaults("3du").sensor  # range 24 cells: from z = 50 the rays leave through z = 63.5
    observe(state, empty_world, np.array([32.0, 32.0, 50.0]), quat, sensor, noise=kinect,
            rng=np.random.default_rng(0), resolution_m=0.05, room_margin_m=0.3)  # fmt: skip
    assert np.all(state != 1)  # the wall is outside the grid
    assert np.all(state[32, 32, 51:64] == 0) and np.all(state[28:37, 28:37, 60:64] == 0)  # measured empty
