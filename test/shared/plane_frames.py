"""Depth frames of a plane 0.6 m in front of a small camera (64 x 48 pixels, 60 degrees wide), as
the CDR bytes ``sim_camera`` publishes: what the ROS tests feed the integrator (``test/shared``
is on the tests' import path; import it after the tests' ``importorskip`` of ROS)."""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.perception import Intrinsics
from nbv_prob_cnn.ros.sim_camera import FrameCdr, frame_cdr

#: One second in nanoseconds, the unit of the frames' stamps.
S = 1_000_000_000
INTRINSICS = Intrinsics.from_hfov(64, 48, 60.0)
#: The plane 0.6 m in front of the camera (metres).
DEPTH = np.full(INTRINSICS.shape, 0.6, np.float32)


def plane_frame(stamp_ns: int, pose: np.ndarray, camera_frame: str, frame_id: str = "world") -> FrameCdr:
    """The plane seen from ``pose`` (4x4, ``frame_id`` <- ``camera_frame``) at ``stamp_ns``: a
    ``16UC1`` image and the camera_info in ``camera_frame``, and the pose."""
    return frame_cdr(DEPTH, INTRINSICS, pose, stamp_ns, "16UC1", frame_id, camera_frame)
