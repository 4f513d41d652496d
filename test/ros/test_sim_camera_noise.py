"""``sim_camera``'s noise parameters (issue 19, deliverable 5): ``noise_preset`` selects the
sensor model of :mod:`nbv_prob_cnn.sensing.sensor_noise`, the older ``noise_sigma_per_m`` /
``noise_dropout`` model stays, and both together are refused."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from nbv_prob_cnn.perception.depth_camera import DepthCamera, DepthNoise, Intrinsics  # noqa: E402
from nbv_prob_cnn.ros.sim_camera import SimCameraConfig, camera_noise  # noqa: E402
from nbv_prob_cnn.sensing.sensor_noise import SensorNoise  # noqa: E402


def test_camera_noise_choices():
    assert camera_noise("", 0.0, 0.0, 0) is None
    old = camera_noise("", 0.01, 0.0, 3)
    assert isinstance(old, DepthNoise) and old.sigma_per_m == 0.01 and old.seed == 3
    kinect = camera_noise("kinect_v1", 0.0, 0.0, 0)
    assert isinstance(kinect, SensorNoise)
    assert (kinect.min_range_m, kinect.max_range_m) == (0.5, 4.0)  # the preset's published range
    with pytest.raises(ValueError, match="choose one noise model"):
        camera_noise("astra", 0.0, 0.02, 0)
    with pytest.raises(ValueError, match="unknown"):
        camera_noise("kinect_v2", 0.0, 0.0, 0)


def test_noise_preset_parameter_lists_the_presets():
    from dataclasses import fields

    field = next(f for f in fields(SimCameraConfig) if f.name == "noise_preset")
    assert field.default == ""
    assert set(field.metadata["param"].choices) == {"", "ideal", "kinect_v1", "astra"}


def _wall(distance: float) -> tuple[np.ndarray, np.ndarray]:
    """A 20 m × 20 m square facing the camera at z = ``distance`` (two triangles)."""
    v = np.array([[-10, -10, distance], [10, -10, distance], [10, 10, distance], [-10, 10, distance]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_preset_camera_sees_only_within_the_sensor_range():
    pytest.importorskip("open3d")
    intrinsics = Intrinsics.from_hfov(32, 24, 60.0)
    pose = np.eye(4)  # optical z along world z, towards the wall
    kinect = camera_noise("kinect_v1", 0.0, 0.0, 0)
    near = DepthCamera([_wall(0.3)], intrinsics, noise=kinect, noise_seed=1).render(pose)
    assert not near.any()  # 0.3 m is inside Kinect v1's 0.5 m minimum range: no return at all
    far = DepthCamera([_wall(5.0)], intrinsics, noise=kinect, noise_seed=1).render(pose)
    assert not far.any()  # beyond its 4 m maximum range
    mid = DepthCamera([_wall(2.0)], intrinsics, noise=kinect, noise_seed=1).render(pose)
    returns = mid[mid > 0]
    # dropout 1 %, no grazing or edges on a frontal wall: nearly every pixel returns, with the axial
    # sigma 0.0012 + 0.0019 * (2.0 - 0.4)^2 = 0.00606 m at 2 m
    assert returns.size >= 0.9 * mid.size
    assert abs(float(returns.mean()) - 2.0) < 0.01
    assert 0.003 < float(returns.std()) < 0.012
    exact = DepthCamera([_wall(2.0)], intrinsics).render(pose)
    assert np.allclose(exact, 2.0, atol=1e-5)
