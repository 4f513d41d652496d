"""TF for our nodes: a listener on ``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``) that
answers lookups as 4×4 matrices. Not a node: a node owns one (``TfListener(self)``).

Uses ``tf2_ros`` (its ``Buffer`` and ``TransformListener``) where it can be imported, as on a
ROS 2 install; otherwise the rclpy-free :class:`~nbv_prob_cnn.perception.tf_buffer.TfBuffer`,
filled by two subscriptions with tf2's QoS (``/tf``: reliable, volatile, depth 100;
``/tf_static``: reliable, transient local, so a late listener still gets the static transforms).
Either way a failed lookup raises :class:`~nbv_prob_cnn.perception.tf_buffer.TransformError`
(``FrameNotFoundError``, ``NotConnectedError`` or ``ExtrapolationError``, the message names the
frame or the time gap), so callers handle one set of errors.

The topic names are absolute, as tf2's: a namespaced robot remaps them (``-r /tf:=tf``).
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from nbv_prob_cnn.perception.messages import stamp_ns as message_stamp_ns
from nbv_prob_cnn.perception.tf_buffer import (
    DEFAULT_CACHE_TIME_S,
    ExtrapolationError,
    FrameNotFoundError,
    NotConnectedError,
    TfBuffer,
    TransformError,
    matrix_from_translation_quaternion,
)

TOPIC_TF = "/tf"
TOPIC_TF_STATIC = "/tf_static"
#: tf2_ros' QoS of the two topics.
TF_QOS = QoSProfile(
    depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)  # fmt: skip
TF_STATIC_QOS = QoSProfile(
    depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)  # fmt: skip
#: The pose sources of our nodes' ``pose_source`` parameter.
POSE_SOURCES = ("tf", "topic")


def tf2_ros_available() -> bool:
    """Whether ``tf2_ros`` imports here (a ROS 2 install)."""
    try:
        import tf2_ros  # noqa: F401
    except ImportError:
        return False
    return True


def transform_msg_matrix(transform) -> np.ndarray:
    """4×4 matrix of a ``geometry_msgs/Transform`` (rclpy or rosbags object).

    Raises:
        ValueError: NaN/inf or a zero quaternion.
    """
    t, q = transform.translation, transform.rotation
    return matrix_from_translation_quaternion((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))


class TfListener:
    """Keeps the TF tree of ``/tf`` + ``/tf_static`` for ``node`` and answers lookups.

    Args:
        node: the node whose subscriptions these are.
        cache_time_s: history kept per dynamic transform.
        callback_group: of the two subscriptions (ours; tf2_ros uses its own).
        prefer_tf2_ros: use tf2_ros where it imports (False: always our buffer).
    """

    def __init__(
        self,
        node: Node,
        cache_time_s: float = DEFAULT_CACHE_TIME_S,
        callback_group=None,
        prefer_tf2_ros: bool = True,
    ) -> None:
        self._node = node
        self.bad_transforms = 0  # refused samples (NaN, zero quaternion, loops) on our buffer
        self._tf2 = None
        if prefer_tf2_ros and tf2_ros_available():
            import tf2_ros
            from rclpy.duration import Duration

            self._tf2 = tf2_ros.Buffer(cache_time=Duration(seconds=cache_time_s))
            self._tf2_listener = tf2_ros.TransformListener(self._tf2, node, spin_thread=False)
            self.backend = "tf2_ros"
            return
        from tf2_msgs.msg import TFMessage  # built from msg_defs/tf2_msgs where no ROS install has it

        self.buffer = TfBuffer(cache_time_s)
        self.backend = "nbv_prob_cnn.perception.tf_buffer"
        node.create_subscription(
            TFMessage, TOPIC_TF, lambda msg: self._on_tf(msg, False), TF_QOS, callback_group=callback_group
        )
        node.create_subscription(
            TFMessage, TOPIC_TF_STATIC, lambda msg: self._on_tf(msg, True), TF_STATIC_QOS,
            callback_group=callback_group,
        )  # fmt: skip

    def _on_tf(self, msg, static: bool) -> None:
        for transform in msg.transforms:
            t, q = transform.transform.translation, transform.transform.rotation
            try:
                self.buffer.set_transform(
                    transform.header.frame_id, transform.child_frame_id, message_stamp_ns(transform.header.stamp),
                    (t.x, t.y, t.z), (q.x, q.y, q.z, q.w), static=static,
                )  # fmt: skip
            except ValueError as exc:
                self.bad_transforms += 1
                self._node.get_logger().warning(
                    f"{TOPIC_TF_STATIC if static else TOPIC_TF}: {exc}; ignored ({self.bad_transforms} so far)",
                    throttle_duration_sec=5.0,
                )

    def lookup(self, target_frame: str, source_frame: str, stamp_ns: int | None = None) -> tuple[np.ndarray, int]:
        """The pose of ``source_frame`` in ``target_frame`` (the matrix mapping source points into
        the target frame) at ``stamp_ns``, or at the newest stamp the chain covers when ``None``;
        returns the matrix and that stamp (ns; 0 for a chain of static transforms).

        Raises:
            TransformError: ``FrameNotFoundError``, ``NotConnectedError`` or ``ExtrapolationError``.
        """
        if self._tf2 is None:
            return self.buffer.lookup(target_frame, source_frame, stamp_ns)
        import tf2_ros
        from rclpy.time import Time

        at = Time() if stamp_ns is None else Time(nanoseconds=int(stamp_ns))
        try:
            msg = self._tf2.lookup_transform(target_frame, source_frame, at)
        except tf2_ros.LookupException as exc:
            raise FrameNotFoundError(str(exc)) from exc
        except tf2_ros.ConnectivityException as exc:
            raise NotConnectedError(str(exc)) from exc
        except tf2_ros.ExtrapolationException as exc:
            raise ExtrapolationError(str(exc)) from exc
        except tf2_ros.TransformException as exc:
            raise TransformError(str(exc)) from exc
        return transform_msg_matrix(msg.transform), message_stamp_ns(msg.header.stamp)

    def can_transform(self, target_frame: str, source_frame: str, stamp_ns: int | None = None) -> bool:
        """Whether :meth:`lookup` would succeed now."""
        try:
            self.lookup(target_frame, source_frame, stamp_ns)
        except TransformError:
            return False
        return True
