"""The integrator's TF posing of depth images (nbv_prob_cnn.perception.tf_poses), without ROS:
a fake lookup, hand-worked cases of pairing, retries and the drop reasons of expired images."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from nbv_prob_cnn.perception.messages import DropReason, StampSync
from nbv_prob_cnn.perception.tf_buffer import ExtrapolationError, FrameNotFoundError
from nbv_prob_cnn.perception.tf_poses import TfPoses

#: The lookup error of an image without a frame id.
NO_FRAME_ID = "the image has no header.frame_id (its optical frame) to look up in TF"


def image(frame_id: str) -> SimpleNamespace:
    return SimpleNamespace(header=SimpleNamespace(frame_id=frame_id))


class FakeTf:
    """A TF lookup that knows ``camera`` in ``world`` (translation x = 1) once ``ready``."""

    def __init__(self) -> None:
        self.ready = False
        self.calls: list[tuple[str, str, int]] = []

    def lookup(self, target: str, source: str, stamp: int) -> tuple[np.ndarray, int]:
        self.calls.append((target, source, stamp))
        if source != "camera":
            raise FrameNotFoundError(f"frame {source!r} does not exist")
        if not self.ready:
            raise ExtrapolationError("no TF after 0.2 s")
        pose = np.eye(4)
        pose[0, 3] = 1.0
        return pose, stamp


def test_tf_poses_pair_retry_and_name_the_tf_failure_when_an_image_expires() -> None:
    sync = StampSync(tolerance_ns=10_000_000, pose_tolerance_ns=0)
    tf = FakeTf()
    poses = TfPoses(sync, tf.lookup, "world")
    sync.add_info(100, "info")
    sync.add_info(200, "info")
    sync.add_info(300, "info")
    # transform not there yet: no frame, the error kept for the retry
    assert poses.pose(100, "camera") == []
    sync.add_image(100, image("camera"), now=0.0)
    assert tf.calls == [("world", "camera", 100)] and isinstance(poses.errors[100], ExtrapolationError)
    # an image without a frame id and one of an unknown frame
    assert poses.pose(200, "") == [] and str(poses.errors[200]) == NO_FRAME_ID
    sync.add_image(200, image(""), now=0.0)
    assert poses.pose(300, "lens") == []
    sync.add_image(300, image("lens"), now=0.0)
    assert poses.to_retry() == [(100, "camera"), (200, ""), (300, "lens")]
    # the transform arrives: the retry of 100 pairs it, posed by TF in the fixed frame
    tf.ready = True
    (paired,) = poses.pose(100, "camera")
    assert paired.stamp_ns == 100 and paired.pose.header.frame_id == "world"
    assert paired.pose.child_frame_id == "camera" and paired.pose.transform.translation.x == pytest.approx(1.0)
    assert 100 not in poses.errors
    # an error of an image no longer waiting (reset) is forgotten
    poses.errors[999] = ExtrapolationError("gone")
    assert poses.to_retry() == [(200, ""), (300, "lens")] and 999 not in poses.errors
    # expired without a pose: counted under the TF failure, the text naming it; other reasons kept
    dropped = [
        (200, DropReason.NO_POSE, "no pose"),
        (300, DropReason.NO_POSE, "no pose"),
        (400, DropReason.NO_CAMERA_INFO, "no camera_info"),
    ]
    assert poses.expired(dropped) == [
        (200, DropReason.TF_UNKNOWN_FRAME, f"no transform from 'world' in TF: {NO_FRAME_ID}"),
        (300, DropReason.TF_UNKNOWN_FRAME, "no transform from 'world' in TF: frame 'lens' does not exist"),
        (400, DropReason.NO_CAMERA_INFO, "no camera_info"),
    ]
    assert poses.errors == {}
