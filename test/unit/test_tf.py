"""TfBuffer (the rclpy-free TF buffer) against hand-worked transform chains: composition along a
chain and across branches, interpolation in time, the newest common stamp, and the errors that
name a missing frame, two trees that do not meet, or the time gap of an extrapolation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nbv_prob_cnn.perception.tf_buffer import (
    ExtrapolationError,
    FrameNotFoundError,
    NotConnectedError,
    TfBuffer,
    TransformError,
)

S = 1_000_000_000  # ns per second
IDENTITY = (0.0, 0.0, 0.0, 1.0)
#: 90 degrees about z: (x, y, z, w) = (0, 0, sin 45°, cos 45°)
Z90 = (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5))


def apply(matrix: np.ndarray, point) -> np.ndarray:
    return (matrix @ np.r_[np.asarray(point, float), 1.0])[:3]


@pytest.fixture
def arm() -> TfBuffer:
    """world -> base: +1 m along x (static); base -> link: 90° about z (dynamic, at 1 s and 2 s);
    link -> camera: +1 m along the link's y (static); base -> side: +2 m along z (static)."""
    tf = TfBuffer()
    tf.set_transform("world", "base", 0, (1.0, 0.0, 0.0), IDENTITY, static=True)
    tf.set_transform("base", "link", 1 * S, (0.0, 0.0, 0.0), Z90)
    tf.set_transform("base", "link", 2 * S, (0.0, 0.0, 0.0), Z90)
    tf.set_transform("link", "camera", 0, (0.0, 1.0, 0.0), IDENTITY, static=True)
    tf.set_transform("base", "side", 0, (0.0, 0.0, 2.0), IDENTITY, static=True)
    return tf


def test_chained_lookup_composes_every_link(arm):
    world_from_camera, stamp = arm.lookup("world", "camera", int(1.5 * S))
    assert stamp == int(1.5 * S)
    # camera (0,0,0) -> link (0,1,0) -> base: rotated 90° about z -> (-1,0,0) -> world (0,0,0)
    np.testing.assert_allclose(apply(world_from_camera, (0, 0, 0)), (0, 0, 0), atol=1e-12)
    # camera (1,0,0) -> link (1,1,0) -> base (-1,1,0) -> world (0,1,0)
    np.testing.assert_allclose(apply(world_from_camera, (1, 0, 0)), (0, 1, 0), atol=1e-12)
    # the camera's x axis points along world +y
    np.testing.assert_allclose(world_from_camera[:3, 0], (0, 1, 0), atol=1e-12)


def test_inverse_and_cross_branch_lookups(arm):
    camera_from_world, _ = arm.lookup("camera", "world", 2 * S)
    np.testing.assert_allclose(apply(camera_from_world, (0, 1, 0)), (1, 0, 0), atol=1e-12)
    # side (0,0,0) is base (0,0,2) = world (1,0,2); in the camera: world (1,0,2) - camera origin (0,0,0)
    # along the camera axes x = world +y, y = world -x, z = world +z: (0, -1, 2)
    camera_from_side, _ = arm.lookup("camera", "side", 2 * S)
    np.testing.assert_allclose(apply(camera_from_side, (0, 0, 0)), (0, -1, 2), atol=1e-12)
    same, _ = arm.lookup("/camera", "camera", 2 * S)  # a leading slash is dropped, as in tf2
    np.testing.assert_allclose(same, np.eye(4), atol=1e-12)


def test_interpolation_in_time():
    tf = TfBuffer()
    tf.set_transform("world", "slider", 1 * S, (0.0, 0.0, 0.0), IDENTITY)
    tf.set_transform("world", "slider", 2 * S, (1.0, 0.0, 0.0), IDENTITY)
    matrix, _ = tf.lookup("world", "slider", int(1.25 * S))
    np.testing.assert_allclose(matrix[:3, 3], (0.25, 0, 0), atol=1e-12)  # a quarter of the way
    tf.set_transform("world", "turntable", 0, (0.0, 0.0, 0.0), IDENTITY)
    tf.set_transform("world", "turntable", 1 * S, (0.0, 0.0, 0.0), Z90)
    matrix, _ = tf.lookup("world", "turntable", S // 2)
    c = math.cos(math.radians(45))
    np.testing.assert_allclose(apply(matrix, (1, 0, 0)), (c, c, 0), atol=1e-12)  # half of 90°
    matrix, _ = tf.lookup("world", "turntable", S)  # at a sample: that sample exactly
    np.testing.assert_allclose(apply(matrix, (1, 0, 0)), (0, 1, 0), atol=1e-12)


def test_interpolation_is_tf2s_when_both_parts_change():
    """tf2 interpolates the translation on a straight line and the rotation along the shorter arc,
    each on its own: from (0, 0, 0) unturned at 0 s to (2, 0, 0) turned 90° about z at 1 s, the
    pose at 0.5 s is (1, 0, 0) turned 45° (a screw motion would leave the straight line)."""
    tf = TfBuffer()
    tf.set_transform("world", "rover", 0, (0.0, 0.0, 0.0), IDENTITY)
    tf.set_transform("world", "rover", 1 * S, (2.0, 0.0, 0.0), Z90)
    matrix, _ = tf.lookup("world", "rover", S // 2)
    c = math.cos(math.radians(45))
    np.testing.assert_allclose(matrix[:3, 3], (1, 0, 0), atol=1e-12)
    np.testing.assert_allclose(matrix[:3, :3] @ (1, 0, 0), (c, c, 0), atol=1e-12)
    # the same rotation written as -q is the same sample: the shorter arc, not a turn the long way
    tf.set_transform("world", "flipped", 0, (0.0, 0.0, 0.0), IDENTITY)
    tf.set_transform("world", "flipped", 1 * S, (0.0, 0.0, 0.0), tuple(-v for v in Z90))
    matrix, _ = tf.lookup("world", "flipped", S // 2)
    np.testing.assert_allclose(matrix[:3, :3] @ (1, 0, 0), (c, c, 0), atol=1e-12)


def test_lookup_in_a_long_history_matches_the_two_samples_around_it():
    """500 samples of a turning, moving frame (10 s at 50 Hz): every lookup between two samples
    equals the hand-worked interpolation of those two (angle and position linear in time)."""
    tf = TfBuffer()
    rate, speed, spin = 50, 0.1, 0.3  # samples per second, m/s along y, rad/s about z
    for k in range(500):
        angle = spin * k / rate
        quaternion = (0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2))
        tf.set_transform("world", "crane", k * S // rate, (0.0, speed * k / rate, 0.0), quaternion)
    for t in (0.013, 3.337, 9.971):
        matrix, _ = tf.lookup("world", "crane", int(t * S))
        np.testing.assert_allclose(matrix[:3, 3], (0, speed * t, 0), atol=1e-9)
        angle = spin * t
        np.testing.assert_allclose(matrix[:3, :3] @ (1, 0, 0), (math.cos(angle), math.sin(angle), 0), atol=1e-9)


def test_samples_out_of_order_and_newest_common_stamp():
    tf = TfBuffer()
    for t, x in ((3, 3.0), (1, 1.0), (2, 2.0)):  # arrive out of order
        tf.set_transform("world", "a", t * S, (x, 0.0, 0.0), IDENTITY)
    tf.set_transform("a", "b", 1 * S, (0.0, 0.0, 0.0), IDENTITY)
    tf.set_transform("a", "b", int(2.5 * S), (0.0, 0.0, 1.0), IDENTITY)
    matrix, stamp = tf.lookup("world", "b")  # None: the newest stamp both transforms cover, 2.5 s
    assert stamp == int(2.5 * S)
    np.testing.assert_allclose(matrix[:3, 3], (2.5, 0, 1), atol=1e-12)
    matrix, _ = tf.lookup("world", "a", int(1.5 * S))
    np.testing.assert_allclose(matrix[:3, 3], (1.5, 0, 0), atol=1e-12)


def test_missing_frame_is_named(arm):
    with pytest.raises(FrameNotFoundError, match="source frame 'gripper' does not exist; known frames: base"):
        arm.lookup("world", "gripper", S)
    with pytest.raises(FrameNotFoundError, match="target frame 'map'"):
        arm.lookup("map", "camera", S)
    with pytest.raises(FrameNotFoundError, match="no transform received yet"):
        TfBuffer().lookup("world", "camera")
    assert not arm.can_transform("world", "gripper") and arm.can_transform("world", "camera")


def test_frames_in_different_trees(arm):
    arm.set_transform("odom", "wheel", 0, (0.0, 0.0, 0.0), IDENTITY, static=True)
    with pytest.raises(NotConnectedError, match="'wheel' and 'camera' are not connected.*'odom'.*'world'"):
        arm.lookup("camera", "wheel", S)


def test_extrapolation_names_the_transform_and_the_gap(arm):
    with pytest.raises(ExtrapolationError, match=r"'base' -> 'link' has data from 1\.000000 s to 2\.000000 s; "
                       r"the request is 0\.500 s after its newest sample"):  # fmt: skip
        arm.lookup("world", "camera", int(2.5 * S))
    with pytest.raises(ExtrapolationError, match=r"0\.250 s before its oldest sample"):
        arm.lookup("world", "camera", int(0.75 * S))
    # static-only chains hold at any stamp
    matrix, _ = arm.lookup("world", "side", 100 * S)
    np.testing.assert_allclose(matrix[:3, 3], (1, 0, 2), atol=1e-12)


def test_history_is_pruned_to_the_cache_time():
    tf = TfBuffer(cache_time_s=1.0)
    for t in range(5):
        tf.set_transform("world", "a", t * S, (float(t), 0.0, 0.0), IDENTITY)
    with pytest.raises(ExtrapolationError, match=r"data from 3\.000000 s to 4\.000000 s"):
        tf.lookup("world", "a", int(2.5 * S))
    matrix, _ = tf.lookup("world", "a", int(3.5 * S))
    np.testing.assert_allclose(matrix[:3, 3], (3.5, 0, 0), atol=1e-12)


def test_reparenting_and_static_replacement():
    tf = TfBuffer()
    tf.set_transform("world", "table", 0, (1.0, 0.0, 0.0), IDENTITY, static=True)
    tf.set_transform("world", "table", 0, (2.0, 0.0, 0.0), IDENTITY, static=True)  # replaces
    tf.set_transform("world", "shelf", 0, (0.0, 5.0, 0.0), IDENTITY, static=True)
    tf.set_transform("table", "cup", 0, (0.0, 0.0, 1.0), IDENTITY, static=True)
    np.testing.assert_allclose(tf.lookup("world", "cup")[0][:3, 3], (2, 0, 1), atol=1e-12)
    tf.set_transform("shelf", "cup", 0, (0.0, 0.0, 0.5), IDENTITY, static=True)  # the cup moves to the shelf
    np.testing.assert_allclose(tf.lookup("world", "cup")[0][:3, 3], (0, 5, 0.5), atol=1e-12)
    assert tf.frames() == ["cup", "shelf", "table", "world"]


@pytest.mark.parametrize(
    "parent, child, quaternion, message",
    [
        ("world", "world", IDENTITY, "its own parent"),
        ("", "a", IDENTITY, "must not be empty"),
        ("world", "a", (0.0, 0.0, 0.0, 0.0), "zero quaternion"),
        ("world", "a", (0.0, 0.0, float("nan"), 1.0), "NaN or infinite"),
        ("camera", "base", IDENTITY, "'base' is an ancestor of 'camera'"),
    ],
)
def test_bad_transforms_are_refused(arm, parent, child, quaternion, message):
    with pytest.raises(ValueError, match=message):
        arm.set_transform(parent, child, S, (0.0, 0.0, 0.0), quaternion)
    np.testing.assert_allclose(apply(arm.lookup("world", "camera", S)[0], (1, 0, 0)), (0, 1, 0), atol=1e-12)


def test_every_error_is_a_transform_error():
    for error in (FrameNotFoundError, NotConnectedError, ExtrapolationError):
        assert issubclass(error, TransformError) and issubclass(error, LookupError)
    assert {FrameNotFoundError.reason, NotConnectedError.reason, ExtrapolationError.reason} == {
        "unknown_frame", "not_connected", "extrapolation",
    }  # fmt: skip


def test_poses_looked_up_per_image_pair_only_with_their_own_image():
    """The integrator's pairing with TF poses (pose tolerance 0): an image takes the pose of its own
    stamp, never a neighbour's 5 ms away (which a 10 ms tolerance would give it)."""
    from nbv_prob_cnn.perception.messages import StampSync

    ms = 1_000_000
    sync = StampSync(10 * ms, pose_tolerance_ns=0)
    for stamp in (100 * ms, 105 * ms):
        sync.add_info(stamp, f"info {stamp}")
    assert sync.add_image(100 * ms, "image 100", 0.0)[0] == []
    assert sync.add_image(105 * ms, "image 105", 0.0)[0] == []
    done = sync.add_pose(100 * ms, "pose 100")
    assert [(f.stamp_ns, f.pose) for f in done] == [(100 * ms, "pose 100")]  # image 105 still waits
    assert list(sync.images) == [105 * ms]
    dropped = sync.expire(10.0, 1.0)
    assert [(stamp, reason.value) for stamp, reason, _ in dropped] == [(105 * ms, "no_pose")]
    loose = StampSync(10 * ms)  # the /camera/pose pairing: the nearest pose within 10 ms
    loose.add_info(105 * ms, "info")
    loose.add_image(105 * ms, "image 105", 0.0)
    assert [f.pose for f in loose.add_pose(100 * ms, "pose 100")] == ["pose 100"]
