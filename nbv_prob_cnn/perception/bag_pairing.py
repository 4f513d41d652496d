"""How the messages of a depth-camera bag become posed frames (read by
:func:`nbv_prob_cnn.perception.bags.read_frames`), in bag order, without ROS.

An image and its camera_info pair by header stamp (the same stamp). The pose comes from what the
bag carries (:func:`pose_source_of`):

* ``topic``: ``/camera/pose`` (``geometry_msgs/TransformStamped``, the simulated bags): the pose
  stamped as the image (:class:`StampPairing`; a frame is the triple of messages sharing a stamp).
* ``tf``: ``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``, as a robot records them, and as
  ``nbv import-rgbd`` writes): the pose of the image's ``header.frame_id`` in the fixed frame at
  the image's stamp, looked up in a :class:`~nbv_prob_cnn.perception.tf_buffer.TfBuffer` filled
  from the bag as it is read (:class:`TfPairing`), as the ``integrator`` node does with
  ``pose_source:=tf``: chained, interpolated between the TF samples around the stamp; an image
  waits until TF covers its stamp, and is given up once the bag's TF has moved on by more than the
  buffer's history (tf2's 10 s) without posing it.

A ``/camera/pose`` bag that also carries ``/tf`` is read by ``/camera/pose``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from nbv_prob_cnn.perception.depth_camera import Intrinsics
from nbv_prob_cnn.perception.messages import (
    MSG_CAMERA_INFO,
    MSG_IMAGE,
    MSG_TRANSFORM,
    WORLD_FRAME,
    camera_info_to_intrinsics,
    image_msg_to_depth,
    stamp_ns,
    stamp_of,
    transform_msg_to_pose,
)
from nbv_prob_cnn.perception.tf_buffer import DEFAULT_CACHE_TIME_S, TfBuffer, TransformError
from nbv_prob_cnn.perception.tf_poses import image_pose_msg

TOPIC_IMAGE = "/camera/depth/image"
TOPIC_CAMERA_INFO = "/camera/depth/camera_info"
TOPIC_POSE = "/camera/pose"
TOPIC_TF = "/tf"
TOPIC_TF_STATIC = "/tf_static"
MSG_TF = "tf2_msgs/msg/TFMessage"
#: Where a bag's poses come from: ``/camera/pose`` or ``/tf`` (+ ``/tf_static``).
POSE_SOURCES = ("topic", "tf")
#: The topics of a depth-camera bag and their types; the camera's two, then the poses'.
CAMERA_TOPICS = {TOPIC_IMAGE: MSG_IMAGE, TOPIC_CAMERA_INFO: MSG_CAMERA_INFO}
POSE_TOPICS = {TOPIC_POSE: MSG_TRANSFORM, TOPIC_TF: MSG_TF, TOPIC_TF_STATIC: MSG_TF}
_NS = 1_000_000_000


@dataclass
class Frame:
    """One posed depth image."""

    stamp_ns: int
    depth_m: np.ndarray  # float32 (H, W) metres, 0 or NaN = no return
    intrinsics: Intrinsics
    pose_4x4: np.ndarray  # float64 world_from_optical


def pose_source_of(topics: Mapping[str, Any]) -> str | None:
    """``topic`` when ``topics`` (a bag's topic names) hold ``/camera/pose``, else ``tf`` when they
    hold ``/tf``, else ``None``."""
    if TOPIC_POSE in topics:
        return "topic"
    return "tf" if TOPIC_TF in topics else None


def topics_read(pose_source: str, topics: Mapping[str, Any]) -> dict[str, str]:
    """The topics (and their types) a frame is made of, of those a bag holds: the camera's two,
    ``/camera/pose`` for ``topic``, ``/tf`` and (where recorded) ``/tf_static`` for ``tf``."""
    poses = (
        [TOPIC_POSE]
        if pose_source == "topic"
        else [TOPIC_TF, *([TOPIC_TF_STATIC] if TOPIC_TF_STATIC in topics else [])]
    )
    return {**CAMERA_TOPICS, **{topic: POSE_TOPICS[topic] for topic in poses}}


def _decode(topic: str, msg: Any) -> Any:
    """The numpy value of a camera-topic message; :class:`ValueError` names the topic and stamp."""
    try:
        if topic == TOPIC_IMAGE:
            return image_msg_to_depth(msg)
        if topic == TOPIC_CAMERA_INFO:
            return camera_info_to_intrinsics(msg)
        return transform_msg_to_pose(msg)
    except ValueError as exc:
        raise ValueError(f"{topic} at stamp {stamp_of(msg)}: {exc}") from exc


def _check_shapes(stamp: int, depth: np.ndarray, intrinsics: Intrinsics) -> None:
    if depth.shape != intrinsics.shape:
        raise ValueError(f"image {depth.shape} and camera_info {intrinsics.shape} disagree at {stamp}")


class StampPairing:
    """Frames of image, camera_info and ``/camera/pose`` messages sharing a header stamp."""

    def __init__(self) -> None:
        self.pending: dict[str, dict[int, Any]] = {topic: {} for topic in (TOPIC_IMAGE, TOPIC_CAMERA_INFO, TOPIC_POSE)}

    def add(self, topic: str, msg: Any) -> list[Frame]:
        """Take one message; returns the frame it completes (if any).

        Raises:
            ValueError: a message that does not decode, a second message of a topic at one stamp,
                image and camera_info of different sizes.
        """
        stamp = stamp_of(msg)
        value = _decode(topic, msg)
        if stamp in self.pending[topic]:
            raise ValueError(f"two {topic} messages with the same stamp {stamp}")
        self.pending[topic][stamp] = value
        if not all(stamp in waiting for waiting in self.pending.values()):
            return []
        depth, intrinsics, pose = (self.pending[t].pop(stamp) for t in (TOPIC_IMAGE, TOPIC_CAMERA_INFO, TOPIC_POSE))
        _check_shapes(stamp, depth, intrinsics)
        return [Frame(stamp, depth, intrinsics, pose)]

    def finish(self) -> str | None:
        """What never formed a frame, in words (``None``: nothing)."""
        leftovers = {topic: len(waiting) for topic, waiting in self.pending.items() if waiting}
        return f"message(s) without a matching stamp on the other topics: {leftovers}" if leftovers else None


@dataclass
class _Unposed:
    """An image paired with its camera_info, waiting for TF to cover its stamp."""

    depth: np.ndarray
    intrinsics: Intrinsics
    frame_id: str
    error: TransformError | None = None  # why the last lookup failed


class TfPairing:
    """Frames of image and camera_info messages sharing a stamp, posed by TF (module docstring).

    The pose takes the road the ``integrator`` node's does (the looked-up matrix, then a
    ``TransformStamped`` and back), so a replay integrates the same poses bit for bit.

    Args:
        fixed_frame: the frame the poses are given in (the grid's).
        cache_time_s: history of each dynamic transform; an image waits at most this long in bag
            time for TF to cover its stamp.
    """

    def __init__(self, fixed_frame: str = WORLD_FRAME, cache_time_s: float = DEFAULT_CACHE_TIME_S) -> None:
        if not fixed_frame:
            raise ValueError("fixed_frame: must not be empty")
        self.fixed_frame = fixed_frame
        self.buffer = TfBuffer(cache_time_s)
        self.images: dict[int, tuple[np.ndarray, str]] = {}
        self.infos: dict[int, Intrinsics] = {}
        self.unposed: dict[int, _Unposed] = {}
        self.given_up: list[tuple[int, TransformError | None]] = []
        self.newest_tf_ns: int | None = None  # the newest dynamic transform's stamp so far

    def add(self, topic: str, msg: Any) -> list[Frame]:
        """Take one message; returns the frames it completes, in stamp order.

        Raises:
            ValueError: a message that does not decode (a transform with NaN/inf, a zero quaternion
                or a loop in the tree included), a second image or camera_info at one stamp, image
                and camera_info of different sizes.
        """
        if topic in (TOPIC_TF, TOPIC_TF_STATIC):
            self._add_transforms(msg, static=topic == TOPIC_TF_STATIC)
            return self._pose_waiting()
        stamp = stamp_of(msg)
        value = _decode(topic, msg)
        if stamp in self.unposed or stamp in (self.images if topic == TOPIC_IMAGE else self.infos):
            raise ValueError(f"two {topic} messages with the same stamp {stamp}")
        if topic == TOPIC_IMAGE:
            self.images[stamp] = (value, str(msg.header.frame_id))
        else:
            self.infos[stamp] = value
        if stamp not in self.images or stamp not in self.infos:
            return []
        (depth, frame_id), intrinsics = self.images.pop(stamp), self.infos.pop(stamp)
        _check_shapes(stamp, depth, intrinsics)
        self.unposed[stamp] = _Unposed(depth, intrinsics, frame_id)
        return self._pose_waiting()

    def _add_transforms(self, msg: Any, static: bool) -> None:
        for transform in msg.transforms:
            stamp = stamp_ns(transform.header.stamp)
            t, q = transform.transform.translation, transform.transform.rotation
            parent, child = str(transform.header.frame_id), str(transform.child_frame_id)
            try:
                self.buffer.set_transform(parent, child, stamp, (t.x, t.y, t.z), (q.x, q.y, q.z, q.w), static)
            except ValueError as exc:
                raise ValueError(f"{TOPIC_TF_STATIC if static else TOPIC_TF} at stamp {stamp}: {exc}") from exc
            if not static:
                self.newest_tf_ns = stamp if self.newest_tf_ns is None else max(self.newest_tf_ns, stamp)

    def _pose_waiting(self) -> list[Frame]:
        """Look up every waiting image; give up those TF has left behind by more than its history."""
        done = []
        for stamp in sorted(self.unposed):
            waiting = self.unposed[stamp]
            try:
                pose_msg = image_pose_msg(self.buffer.lookup, self.fixed_frame, waiting.frame_id, stamp)
            except TransformError as exc:
                waiting.error = exc
                if self.newest_tf_ns is not None and self.newest_tf_ns - stamp > self.buffer.cache_ns:
                    self.given_up.append((stamp, exc))
                    del self.unposed[stamp]
                continue
            del self.unposed[stamp]
            pose = transform_msg_to_pose(pose_msg)
            done.append(Frame(stamp, waiting.depth, waiting.intrinsics, pose))
        return done

    def finish(self) -> str | None:
        """What never formed a frame, in words (``None``: nothing): images or camera_infos without
        a partner, and images that TF never posed (with the last lookup's error)."""
        parts = []
        unpaired = {topic: len(w) for topic, w in ((TOPIC_IMAGE, self.images), (TOPIC_CAMERA_INFO, self.infos)) if w}
        if unpaired:
            parts.append(f"message(s) without a matching stamp on the other topics: {unpaired}")
        never = self.given_up + [(stamp, waiting.error) for stamp, waiting in sorted(self.unposed.items())]
        if never:
            stamp, error = never[-1]
            parts.append(
                f"{len(never)} image(s) without a transform from {self.fixed_frame!r} in /tf at their stamp "
                f"(the last, at {stamp / _NS:.6f} s: {error})"
            )
        return "; ".join(parts) or None
