"""A camera that stands still costs little: the depth camera casts rays once per pose (the noise
is drawn anew for every frame), and the still-frame filter keeps the first N frames of each pose.
Checked against a camera that casts every frame and against hand-worked pose sequences."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("open3d")
trimesh = pytest.importorskip("trimesh")

from nbv_prob_cnn.basics.camera import look_rotation  # noqa: E402
from nbv_prob_cnn.perception import DepthCamera, Intrinsics  # noqa: E402
from nbv_prob_cnn.perception.depth_camera import MeshScene  # noqa: E402
from nbv_prob_cnn.perception.still_frames import StillFrameFilter  # noqa: E402
from nbv_prob_cnn.sensing.sensor_noise import sensor_noise  # noqa: E402

INTRINSICS = Intrinsics.from_hfov(80, 60, 60.0)


def look_at(position, target=(0.5, 0.5, 0.2)) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(np.asarray(target, float) - np.asarray(position, float))
    pose[:3, 3] = position
    return pose


def box_meshes() -> list:
    return [trimesh.creation.box(bounds=np.array([[0.2, 0.2, 0.0], [0.8, 0.8, 0.4]]))]


def test_a_still_camera_casts_once_and_draws_its_noise_anew() -> None:
    a, b = look_at([0.5, -0.4, 0.9]), look_at([1.3, 0.5, 0.8])
    poses = [a, a, a, b, b, a]
    cached = DepthCamera(box_meshes(), INTRINSICS, noise=sensor_noise("kinect_v1"), noise_seed=3)
    reference = DepthCamera(box_meshes(), INTRINSICS, noise=sensor_noise("kinect_v1"), noise_seed=3)
    images = [cached.render(p) for p in poses]
    expected = []
    for p in poses:
        reference._last = None  # the reference casts every frame
        expected.append(reference.render(p))
    assert cached.renders == 3 and reference.renders == 6  # a, b, a again
    for got, want in zip(images, expected, strict=True):
        np.testing.assert_array_equal(got, want)
    assert not np.array_equal(images[0], images[1])  # the same pose, a fresh noise draw
    assert np.count_nonzero(images[0]) > 1000


def test_the_exact_image_is_returned_as_a_copy_and_a_new_occluder_is_cast() -> None:
    camera = DepthCamera(box_meshes(), INTRINSICS)
    pose = look_at([0.5, 0.5, 1.2])
    first = camera.render(pose)
    first[:] = 0.0  # the caller's copy: the kept image is not changed
    again = camera.render(pose)
    assert camera.renders == 1 and np.count_nonzero(again) > 1000
    np.testing.assert_array_equal(again, DepthCamera(box_meshes(), INTRINSICS).render(pose))
    # an occluder between the camera and the box: a new object, so a new cast; the top of the
    # box (z = 0.4, 0.8 m below) is now hidden behind the plate at z = 0.7 (0.5 m below)
    plate = MeshScene([trimesh.creation.box(bounds=np.array([[0.4, 0.4, 0.69], [0.6, 0.6, 0.7]]))])
    occluded = camera.render(pose, [plate])
    assert camera.renders == 2
    centre = occluded[INTRINSICS.height // 2, INTRINSICS.width // 2]
    assert centre == pytest.approx(0.5, abs=1e-4) and again[INTRINSICS.height // 2, INTRINSICS.width // 2] == (
        pytest.approx(0.8, abs=1e-4)
    )
    camera.render(pose, [plate])
    assert camera.renders == 2


def rotated(pose: np.ndarray, degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    turn = np.eye(4)
    turn[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    return pose @ turn


def shifted(pose: np.ndarray, metres: float) -> np.ndarray:
    out = pose.copy()
    out[0, 3] += metres
    return out


def test_still_frame_filter_keeps_the_first_frames_of_each_pose() -> None:
    a = look_at([0.5, -0.4, 0.9])
    b = shifted(a, 0.1)
    still = StillFrameFilter(2)  # tolerances 0.5 mm, 0.1 deg, 1 mrad
    decisions = [still.should_fuse(p) for p in (a, a, a, shifted(a, 4e-4), rotated(a, 0.05), b, b, b, a)]
    assert decisions == [True, True, False, False, False, True, True, False, True]
    # just outside the tolerances: a new pose each time (measured from the spell's first frame)
    still = StillFrameFilter(1)
    assert [still.should_fuse(p) for p in (a, a, shifted(a, 6e-4), rotated(shifted(a, 6e-4), 0.2))] == [
        True, False, True, True,
    ]  # fmt: skip
    # joints: the arm moving under a still camera starts a new spell; a reset too
    still = StillFrameFilter(1)
    q = [0.1, -0.2, 0.3]
    assert still.should_fuse(a, q) and not still.should_fuse(a, [0.1, -0.2, 0.3005])
    assert still.should_fuse(a, [0.1, -0.2, 0.302]) and not still.should_fuse(a, [0.1, -0.2, 0.302])
    assert still.should_fuse(a, None)  # joints missing where they were given: not the same
    still.reset()
    assert still.should_fuse(a, None) and not still.should_fuse(a, None)
    # 0: every frame
    every = StillFrameFilter(0)
    assert all(every.should_fuse(a) for _ in range(5))
    for bad in ((-1,), (1, -0.1), (1, 0.001, math.nan)):
        with pytest.raises(ValueError, match="finite and >= 0"):
            StillFrameFilter(*bad)


def test_a_still_camera_posed_by_tf_casts_once() -> None:
    """Poses looked up in TF between two equal samples differ in their last bits (interpolation):
    the camera still counts them as one pose; a shift of a micrometre is a new one."""
    from nbv_prob_cnn.perception.tf_buffer import TfBuffer

    s = 10**9
    pose = look_at([0.5, -0.4, 0.9])
    xyzw = xyzw_of(pose[:3, :3])
    tf = TfBuffer()
    for stamp in (1 * s, 2 * s):  # the arm stands still: two equal samples
        tf.set_transform("world", "camera", stamp, pose[:3, 3], xyzw)
    looked_up = [tf.lookup("world", "camera", s + k * s // 7)[0] for k in range(1, 7)]
    assert any(not np.array_equal(p, looked_up[0]) for p in looked_up)  # not bit-equal (why the tolerance)
    camera = DepthCamera(box_meshes(), INTRINSICS)
    images = [camera.render(p) for p in looked_up]
    assert camera.renders == 1
    exact = DepthCamera(box_meshes(), INTRINSICS).render(pose)
    for image in images:
        np.testing.assert_allclose(image, exact, atol=1e-6)
    camera.render(shifted(looked_up[0], 1e-6))
    assert camera.renders == 2


def xyzw_of(rotation: np.ndarray) -> np.ndarray:
    """Quaternion ``(x, y, z, w)`` of a rotation matrix (pytransform3d gives ``(w, x, y, z)``)."""
    from pytransform3d.rotations import quaternion_from_matrix

    w, x, y, z = quaternion_from_matrix(rotation)
    return np.array([x, y, z, w])
