"""Depth-camera messages without rclpy: the codecs between ``rosbags`` message objects and numpy
(REP-118 depth images, camera_info, TransformStamped poses), header-stamp conversion, and the
stamp synchronisation that pairs each image with its camera_info and pose.

Used by the bag reader/writer (:mod:`nbv_prob_cnn.perception.bags`) and by the ROS nodes, which
take raw CDR bytes and decode them here. Every reason to drop a frame has a name
(:class:`DropReason`), so a node can count and report each one (no frame is dropped silently).
"""

from __future__ import annotations

import bisect
import enum
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from nbv_prob_cnn.basics.camera import matrix_from_quaternion, quaternion_from_matrix
from nbv_prob_cnn.perception.depth_camera import Intrinsics, check_pose

WORLD_FRAME = "world"
OPTICAL_FRAME = "camera_optical"
MSG_IMAGE = "sensor_msgs/msg/Image"
MSG_CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
MSG_TRANSFORM = "geometry_msgs/msg/TransformStamped"
MSG_JOINT_STATE = "sensor_msgs/msg/JointState"
#: REP-118 depth encodings: ``32FC1`` metres, ``16UC1`` millimetres (0 or NaN = no return).
ENCODINGS = ("32FC1", "16UC1")
_ENCODINGS = {"32FC1": ("f4", 4), "16UC1": ("u2", 2)}
#: Images waiting for their pose/camera_info at most (older ones are dropped beyond it).
MAX_PENDING = 64
#: Poses and camera_infos kept for pairing.
HISTORY = 256
_NS = 1_000_000_000


class DropReason(str, enum.Enum):
    """Why a depth frame was not integrated (the value is the counter's name)."""

    BAD_MESSAGE = "bad_message"  # the CDR bytes do not decode
    BAD_ENCODING = "bad_encoding"  # not a REP-118 depth encoding
    SIZE_MISMATCH = "size_mismatch"  # image data vs. its own sizes, or image vs. camera_info
    NON_FINITE_POSE = "non_finite_pose"  # NaN/inf pose or a zero quaternion
    POSE_FRAME = "pose_frame"  # pose_source topic: pose in another frame than the grid's
    TF_UNKNOWN_FRAME = "tf_unknown_frame"  # pose_source tf: the image's frame (or the grid's) never on /tf
    TF_NOT_CONNECTED = "tf_not_connected"  # pose_source tf: the image's frame is in another TF tree
    TF_EXTRAPOLATION = "tf_extrapolation"  # pose_source tf: no TF around the image's stamp before the timeout
    NO_POSE = "no_pose"  # no pose within the sync tolerance before the timeout
    NO_CAMERA_INFO = "no_camera_info"  # no camera_info within the tolerance before the timeout
    NO_JOINT_STATES = "no_joint_states"  # self-filter on: no joint_states within the tolerance before the timeout
    BAD_JOINT_STATES = "bad_joint_states"  # self-filter on: joint_states with unknown/missing joints or bad values
    TOO_MANY_PENDING = "too_many_pending"  # more than MAX_PENDING images waiting for partners
    BEHIND = "behind"  # integration fell behind (drop_when_behind)
    RESET = "reset"  # waiting when the grid was reset
    INTEGRATION_ERROR = "integration_error"  # the TSDF refused the frame


class FrameRejectedError(ValueError):
    """A message or frame that cannot be integrated, with the :class:`DropReason`."""

    def __init__(self, reason: DropReason, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class DropCounts:
    """Frames dropped per :class:`DropReason` (every reason present, zero until it happens)."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter({reason.value: 0 for reason in DropReason})

    def add(self, reason: DropReason, n: int = 1) -> None:
        self.counts[reason.value] += n

    def total(self) -> int:
        return sum(self.counts.values())

    def as_dict(self) -> dict[str, int]:
        return {reason.value: int(self.counts[reason.value]) for reason in DropReason}


# --------------------------------------------------------------------------------- stamps
def stamp_ns(stamp: Any) -> int:
    """Nanoseconds of a ``builtin_interfaces/Time`` (rclpy or rosbags object: ``sec``, ``nanosec``)."""
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def stamp_parts(ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of a stamp in nanoseconds.

    Raises:
        ValueError: a negative stamp.
    """
    ns = int(ns)
    if ns < 0:
        raise ValueError(f"stamp: must be >= 0 ns, got {ns}")
    return ns // _NS, ns % _NS


# --------------------------------------------------------------------------------- codecs
@lru_cache(maxsize=1)
def typestore() -> Any:
    """The ROS 2 Jazzy message type store."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


# ----------------------------------------------------------------------------- conversions
def _header(stamp_ns: int, frame_id: str) -> Any:
    types = typestore().types
    sec, nanosec = stamp_parts(stamp_ns)
    return types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                        frame_id=frame_id)  # fmt: skip


def stamp_of(msg: Any) -> int:
    """Header stamp of a message in nanoseconds."""
    return stamp_ns(msg.header.stamp)


def depth_to_image_msg(
    depth_m: np.ndarray, stamp_ns: int, encoding: str = "32FC1", frame_id: str = OPTICAL_FRAME
) -> Any:
    """A ``sensor_msgs/msg/Image`` of a depth image.

    Args:
        depth_m: ``(H, W)`` depth in metres (0/NaN = no return), or ``uint16`` millimetres when
            ``encoding`` is ``16UC1``.
        encoding: ``32FC1`` (float metres, written as given, NaN kept) or ``16UC1`` (millimetres,
            rounded; no return, negative and > 65.535 m become 0).

    Raises:
        ValueError: another encoding, or not a 2D image.
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2:
        raise ValueError(f"depth: expected a 2D (H, W) image, got shape {depth.shape}")
    if encoding == "32FC1":
        data = depth.astype("<f4")
    elif encoding == "16UC1":
        if depth.dtype == np.uint16:
            data = depth.astype("<u2")
        else:
            mm = np.round(np.asarray(depth, dtype=np.float64) * 1000.0)
            mm[~np.isfinite(mm) | (mm <= 0) | (mm > 65535)] = 0
            data = mm.astype("<u2")
    else:
        raise ValueError(f"depth image encoding {encoding!r} is not supported; use '32FC1' (m) or '16UC1' (mm)")
    height, width = depth.shape
    return typestore().types[MSG_IMAGE](
        header=_header(stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * data.itemsize,
        data=np.frombuffer(np.ascontiguousarray(data).tobytes(), dtype=np.uint8),
    )


def image_msg_to_depth(msg: Any) -> np.ndarray:
    """Depth in ``float32`` metres of a ``sensor_msgs/msg/Image`` (32FC1 metres or 16UC1 mm).

    Handles row padding (``step`` > width × pixel size) and big-endian data. 16UC1 value 0
    stays 0 (no return); 32FC1 values are returned as stored (NaN kept).

    Raises:
        FrameRejectedError: (a ``ValueError``) an unsupported encoding (named in the message, reason
            ``bad_encoding``), or inconsistent sizes (``size_mismatch``).
    """
    encoding = str(msg.encoding)
    if encoding not in _ENCODINGS:
        raise FrameRejectedError(
            DropReason.BAD_ENCODING,
            f"depth image encoding {encoding!r} is not supported; expected '32FC1' (metres) or '16UC1' (millimetres)",
        )
    kind, size = _ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if step < width * size:
        raise FrameRejectedError(
            DropReason.SIZE_MISMATCH, f"depth image: step {step} is smaller than width {width} x {size} bytes"
        )
    raw = np.asarray(msg.data, dtype=np.uint8)
    if raw.size < step * height:
        raise FrameRejectedError(
            DropReason.SIZE_MISMATCH, f"depth image: {raw.size} data bytes, expected step x height = {step * height}"
        )
    rows = raw[: step * height].reshape(height, step)[:, : width * size]
    dtype = np.dtype((">" if msg.is_bigendian else "<") + kind)
    values = np.ascontiguousarray(rows).view(dtype).reshape(height, width)
    if encoding == "16UC1":
        return values.astype(np.float32) / np.float32(1000.0)
    return values.astype(np.float32)


def intrinsics_to_camera_info(intrinsics: Intrinsics, stamp_ns: int, frame_id: str = OPTICAL_FRAME) -> Any:
    """A ``sensor_msgs/msg/CameraInfo`` (plumb_bob, zero distortion) of pinhole intrinsics."""
    types = typestore().types
    fx, fy, cx, cy = (float(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy))
    return types[MSG_CAMERA_INFO](
        header=_header(stamp_ns, frame_id),
        height=int(intrinsics.height),
        width=int(intrinsics.width),
        distortion_model="plumb_bob",
        d=np.zeros(5, dtype=np.float64),
        k=np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]),
        r=np.eye(3).reshape(9),
        p=np.array([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]),
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def camera_info_to_intrinsics(msg: Any) -> Intrinsics:
    """Pinhole intrinsics (from ``K``) of a ``sensor_msgs/msg/CameraInfo``.

    Raises:
        ValueError: ``K`` missing or not a valid pinhole matrix.
    """
    k = np.asarray(msg.k, dtype=np.float64).reshape(-1)
    if k.size != 9:
        raise ValueError(f"camera_info: K must have 9 values, got {k.size}")
    return Intrinsics(int(msg.width), int(msg.height), float(k[0]), float(k[4]), float(k[2]), float(k[5]))


def pose_to_transform_msg(
    pose_4x4: np.ndarray, stamp_ns: int, parent: str = WORLD_FRAME, child: str = OPTICAL_FRAME
) -> Any:
    """A ``geometry_msgs/msg/TransformStamped`` (parent -> child) of a 4×4 ``parent_from_child`` pose."""
    pose = check_pose(pose_4x4, "pose_4x4")
    types = typestore().types
    qx, qy, qz, qw = (float(v) for v in quaternion_from_matrix(pose[:3, :3]))
    tx, ty, tz = (float(v) for v in pose[:3, 3])
    transform = types["geometry_msgs/msg/Transform"](
        translation=types["geometry_msgs/msg/Vector3"](x=tx, y=ty, z=tz),
        rotation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )
    return types[MSG_TRANSFORM](header=_header(stamp_ns, parent), child_frame_id=child, transform=transform)


def transform_msg_to_pose(msg: Any) -> np.ndarray:
    """4×4 ``parent_from_child`` matrix of a ``geometry_msgs/msg/TransformStamped``.

    Raises:
        FrameRejectedError: (``non_finite_pose``) NaN/inf translation or rotation, or a zero quaternion.
    """
    t, q = msg.transform.translation, msg.transform.rotation
    values = np.array([t.x, t.y, t.z, q.x, q.y, q.z, q.w], dtype=np.float64)
    if not np.all(np.isfinite(values)) or np.linalg.norm(values[3:]) < 1e-9:
        raise FrameRejectedError(
            DropReason.NON_FINITE_POSE,
            f"pose: expected finite values and a non-zero quaternion, "
            f"got t={values[:3].tolist()} q={values[3:].tolist()}",
        )
    pose = np.eye(4)
    pose[:3, :3] = matrix_from_quaternion(np.array([q.x, q.y, q.z, q.w]))
    pose[:3, 3] = [t.x, t.y, t.z]
    return pose


# ------------------------------------------------------------------------ synchronisation
@dataclass
class PairedFrame:
    """Image, camera_info and pose messages (rosbags objects) of one stamp, and the joint
    states when the sync requires them (else ``None``)."""

    stamp_ns: int
    image: Any
    info: Any
    pose: Any
    generation: int = 0
    joints: Any = None


class StampSync:
    """Pairs each image with the camera_info and the pose nearest to its stamp within a tolerance.

    Not thread-safe (the node calls it under its lock). Poses and camera_infos are kept (the
    newest :data:`HISTORY`) and may serve several images; an image waits until both partners
    are there, or is dropped by :meth:`expire`. With ``require_joints`` an image also needs the
    joint states nearest to its stamp within the tolerance (a third partner, kept the same way),
    settled: only once joint states stamped at or after the image have arrived, since a nearer
    one could still come (joint states stream at a high rate; the arm moves between them).
    """

    def __init__(self, tolerance_ns: int, require_joints: bool = False, pose_tolerance_ns: int | None = None) -> None:
        self.tolerance_ns = int(tolerance_ns)
        #: poses may differ from their image's stamp by this much (default ``tolerance_ns``; 0 when
        #: poses are looked up at each image's own stamp, as by TF)
        self.pose_tolerance_ns = self.tolerance_ns if pose_tolerance_ns is None else int(pose_tolerance_ns)
        self.require_joints = bool(require_joints)
        self.images: dict[int, tuple[Any, float]] = {}  # stamp -> (message, arrival time.monotonic())
        self.infos: list[tuple[int, Any]] = []  # sorted by stamp
        self.poses: list[tuple[int, Any]] = []
        self.joints: list[tuple[int, Any]] = []

    def clear(self) -> None:
        self.images.clear()
        self.infos.clear()
        self.poses.clear()
        self.joints.clear()

    @staticmethod
    def _insert(history: list[tuple[int, Any]], stamp: int, msg: Any) -> None:
        i = bisect.bisect_left(history, stamp, key=lambda item: item[0])
        if i < len(history) and history[i][0] == stamp:
            history[i] = (stamp, msg)  # a repeated stamp replaces the older message
        else:
            history.insert(i, (stamp, msg))
        del history[:-HISTORY]

    def nearest(
        self, history: list[tuple[int, Any]], stamp: int, tolerance_ns: int | None = None
    ) -> tuple[int, Any] | None:
        """The entry of ``history`` nearest to ``stamp`` within the tolerance (default
        ``tolerance_ns``; ties: the older)."""
        tolerance = self.tolerance_ns if tolerance_ns is None else tolerance_ns
        i = bisect.bisect_left(history, stamp, key=lambda item: item[0])
        best = None
        for j in (i - 1, i):
            if (
                0 <= j < len(history)
                and abs(history[j][0] - stamp) <= tolerance
                and (best is None or abs(history[j][0] - stamp) < abs(best[0] - stamp))
            ):
                best = history[j]
        return best

    def add_image(self, stamp: int, msg: Any, now: float) -> tuple[list[PairedFrame], list[int]]:
        """Returns the frames completed and the stamps of images dropped for lack of room."""
        self.images[stamp] = (msg, now)
        overflow = []
        while len(self.images) > MAX_PENDING:
            oldest = min(self.images)
            del self.images[oldest]
            overflow.append(oldest)
        return self._complete(), overflow

    def add_info(self, stamp: int, msg: Any) -> list[PairedFrame]:
        self._insert(self.infos, stamp, msg)
        return self._complete()

    def add_pose(self, stamp: int, msg: Any) -> list[PairedFrame]:
        self._insert(self.poses, stamp, msg)
        return self._complete()

    def add_joints(self, stamp: int, msg: Any) -> list[PairedFrame]:
        self._insert(self.joints, stamp, msg)
        return self._complete()

    def settled_nearest(self, history: list[tuple[int, Any]], stamp: int) -> tuple[int, Any] | None:
        """:meth:`nearest`, once ``history`` holds a message stamped at or after ``stamp``."""
        if not history or history[-1][0] < stamp:
            return None
        return self.nearest(history, stamp)

    def _complete(self) -> list[PairedFrame]:
        done = []
        for stamp in sorted(self.images):
            info = self.nearest(self.infos, stamp)
            pose = self.nearest(self.poses, stamp, self.pose_tolerance_ns)
            joints = self.settled_nearest(self.joints, stamp) if self.require_joints else (0, None)
            if info is not None and pose is not None and joints is not None:
                image, _ = self.images.pop(stamp)
                done.append(PairedFrame(stamp, image, info[1], pose[1], joints=joints[1]))
        return done

    def _missing(self, stamp: int) -> list[tuple[str, DropReason, list[tuple[int, Any]]]]:
        """The partners an image still lacks: ``(name, drop reason, history)``."""
        missing = [
            (name, reason, history)
            for name, reason, history, tolerance in (
                ("pose", DropReason.NO_POSE, self.poses, self.pose_tolerance_ns),
                ("camera_info", DropReason.NO_CAMERA_INFO, self.infos, self.tolerance_ns),
            )
            if self.nearest(history, stamp, tolerance) is None
        ]
        if self.require_joints and self.settled_nearest(self.joints, stamp) is None:
            missing.append(("joint_states", DropReason.NO_JOINT_STATES, self.joints))
        return missing

    def expire(self, now: float, timeout_s: float) -> list[tuple[int, DropReason, str]]:
        """Drop images that waited longer than ``timeout_s``; returns ``(stamp, reason, text)``."""
        dropped = []
        for stamp in sorted(self.images):
            _, arrived = self.images[stamp]
            if now - arrived <= timeout_s:
                continue
            del self.images[stamp]
            reasons = []
            missing = self._missing(stamp)
            kind = missing[0][1] if missing else DropReason.NO_POSE
            for name, _, history in missing:
                if not history:
                    reasons.append(f"no {name} received yet")
                elif self.nearest(history, stamp) is not None:  # joint states: none at or after the image
                    offset = (history[-1][0] - stamp) * 1e-9
                    reasons.append(f"no {name} stamped at or after the image (newest is {offset:+.3f} s away)")
                else:
                    closest = min(history, key=lambda item: abs(item[0] - stamp))
                    offset = (closest[0] - stamp) * 1e-9
                    reasons.append(
                        f"no {name} within ±{self.tolerance_ns * 1e-9:g} s (nearest is {offset:+.3f} s away)"
                    )
            dropped.append((stamp, kind, "; ".join(reasons)))
        return dropped


def decode_frame(frame: PairedFrame) -> tuple[np.ndarray, Intrinsics, np.ndarray]:
    """Depth (float32 m), intrinsics and 4×4 pose of a paired frame, checked for integration.

    Raises:
        FrameRejectedError: with the reason: bad encoding, image data or image vs. camera_info size
            mismatch, non-finite pose (or a pose that is not a rigid transform).
    """
    depth = image_msg_to_depth(frame.image)
    try:
        intrinsics = camera_info_to_intrinsics(frame.info)
    except ValueError as exc:
        raise FrameRejectedError(DropReason.SIZE_MISMATCH, str(exc)) from exc
    if depth.shape != intrinsics.shape:
        raise FrameRejectedError(
            DropReason.SIZE_MISMATCH,
            f"image {depth.shape[1]}x{depth.shape[0]} does not match "
            f"camera_info {intrinsics.width}x{intrinsics.height}",
        )
    pose = transform_msg_to_pose(frame.pose)
    try:
        pose = check_pose(pose, "pose")
    except ValueError as exc:
        raise FrameRejectedError(DropReason.NON_FINITE_POSE, str(exc)) from exc
    return depth, intrinsics, pose


# ------------------------------------------------------------------------ planning results
MSG_POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
MSG_POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
MSG_MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"


def points_to_cloud_msg(points: np.ndarray, stamp: int, frame_id: str = WORLD_FRAME) -> Any:
    """A ``sensor_msgs/msg/PointCloud2`` (x, y, z float32, unorganised) of ``(N, 3)`` points."""
    types = typestore().types
    xyz = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, 3))
    field = types["sensor_msgs/msg/PointField"]
    fields = [field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]  # 7 = FLOAT32
    return types[MSG_POINT_CLOUD](
        header=_header(stamp, frame_id), height=1, width=len(xyz), fields=fields, is_bigendian=False,
        point_step=12, row_step=12 * len(xyz), data=np.frombuffer(xyz.tobytes(), dtype=np.uint8), is_dense=True,
    )  # fmt: skip


def cloud_msg_to_points(msg: Any) -> np.ndarray:
    """``(N, 3)`` float32 points of a PointCloud2 with float32 x, y, z fields.

    Raises:
        ValueError: missing x/y/z float32 fields or inconsistent sizes.
    """
    offsets = {f.name: int(f.offset) for f in msg.fields if int(f.datatype) == 7}
    if not {"x", "y", "z"} <= set(offsets):
        raise ValueError("point cloud: expected float32 fields x, y, z")
    n, step = int(msg.width) * int(msg.height), int(msg.point_step)
    raw = np.asarray(msg.data, dtype=np.uint8)
    if raw.size < n * step:
        raise ValueError(f"point cloud: {raw.size} data bytes, expected {n} x {step}")
    rows = raw[: n * step].reshape(n, step)
    dtype = np.dtype(">f4" if msg.is_bigendian else "<f4")
    return np.stack([rows[:, offsets[a] : offsets[a] + 4].copy().view(dtype)[:, 0] for a in "xyz"], axis=1)
