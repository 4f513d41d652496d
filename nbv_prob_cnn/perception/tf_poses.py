"""``pose_source:=tf``: each depth image posed by a TF lookup at its stamp, without ROS (the lookup
is given: the node's :class:`~nbv_prob_cnn.ros.tf_listener.TfListener`, or a
:class:`~nbv_prob_cnn.perception.tf_buffer.TfBuffer`).

The pose of the image's ``header.frame_id`` (the camera's optical frame) in the grid's fixed frame
is added to the :class:`~nbv_prob_cnn.perception.messages.StampSync` as the image's pose. An image
whose transform is not there yet keeps its lookup error: it is retried (:meth:`TfPoses.to_retry`)
and, when the sync drops it for want of a pose, counted under that TF failure
(:meth:`TfPoses.expired`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from nbv_prob_cnn.perception.messages import DropReason, PairedFrame, StampSync, pose_to_transform_msg
from nbv_prob_cnn.perception.tf_buffer import TransformError

#: The drop reason of an image whose TF lookup failed, by :attr:`TransformError.reason`.
TF_DROP_REASONS = {
    "unknown_frame": DropReason.TF_UNKNOWN_FRAME,
    "not_connected": DropReason.TF_NOT_CONNECTED,
    "extrapolation": DropReason.TF_EXTRAPOLATION,
}
#: ``lookup(target_frame, source_frame, stamp_ns)``: the 4x4 pose of the source frame in the target
#: frame and the stamp it holds for; raises :class:`TransformError`.
Lookup = Callable[[str, str, int], tuple[np.ndarray, int]]


def image_pose_msg(lookup: Lookup, fixed_frame: str, frame: str, stamp: int) -> Any:
    """The pose of image frame ``frame`` (its ``header.frame_id``) in ``fixed_frame`` at ``stamp``, as
    the ``TransformStamped`` a pose topic would carry (the node and the bag reader take the same road,
    so both integrate the same poses bit for bit).

    Raises:
        TransformError: no frame to look up, or TF cannot give the transform (yet).
    """
    if not frame:
        raise TransformError("the image has no header.frame_id (its optical frame) to look up in TF")
    matrix, _ = lookup(fixed_frame, frame, stamp)
    return pose_to_transform_msg(matrix, stamp, fixed_frame, frame)


class TfPoses:
    """The TF poses of the images of a :class:`StampSync` in ``fixed_frame``. Not thread-safe (the
    node calls it under the sync's lock)."""

    def __init__(self, sync: StampSync, lookup: Lookup, fixed_frame: str) -> None:
        self.errors: dict[int, TransformError] = {}  # image stamp -> why its last TF lookup failed
        self._sync = sync
        self._lookup = lookup
        self._fixed_frame = fixed_frame

    def pose(self, stamp: int, frame: str) -> list[PairedFrame]:
        """Add the pose of image frame ``frame`` at ``stamp`` to the sync and return the frames it
        completes; none when the transform is not available (yet): the error is kept in :attr:`errors`."""
        try:
            pose = image_pose_msg(self._lookup, self._fixed_frame, frame, stamp)
        except TransformError as exc:
            self.errors[stamp] = exc
            return []
        self.errors.pop(stamp, None)
        return self._sync.add_pose(stamp, pose)

    def to_retry(self) -> list[tuple[int, str]]:
        """``(stamp, frame)`` of every image still waiting in the sync whose lookup failed, in stamp
        order (the errors of images paired, expired or reset since are forgotten)."""
        waiting = {stamp: msg for stamp, (msg, _) in self._sync.images.items()}
        for stamp in list(self.errors):
            if stamp not in waiting:
                del self.errors[stamp]
        return [(stamp, waiting[stamp].header.frame_id) for stamp in sorted(s for s in waiting if s in self.errors)]

    def expired(self, dropped: list[tuple[int, DropReason, str]]) -> list[tuple[int, DropReason, str]]:
        """The sync's expired images (:meth:`StampSync.expire`), those without a pose under the TF
        failure of their last lookup (its text naming the frame or the time gap)."""
        out = []
        for stamp, reason, text in dropped:
            error = self.errors.pop(stamp, None)
            if error is not None and reason == DropReason.NO_POSE:
                reason = TF_DROP_REASONS.get(error.reason, DropReason.TF_UNKNOWN_FRAME)
                text = f"no transform from {self._fixed_frame!r} in TF: {error}"
            out.append((stamp, reason, text))
        return out
