"""Depth-camera rosbag2 files (mcap storage) written and read with ``rosbags`` — no ROS needed.

Topics (the defaults of docs/method.md#node-graph):
    * ``/camera/depth/image``        ``sensor_msgs/msg/Image``, ``32FC1`` metres or ``16UC1`` millimetres
    * ``/camera/depth/camera_info``  ``sensor_msgs/msg/CameraInfo`` (pinhole ``K``; rectified images assumed)
    * the pose ``world`` -> the image's ``header.frame_id`` (``camera_optical``), stamped as the image, on
        * ``/camera/pose``           ``geometry_msgs/msg/TransformStamped`` (the simulated bags), or
        * ``/tf``                    ``tf2_msgs/msg/TFMessage`` (+ ``/tf_static``: a robot's recording, and
          ``nbv import-rgbd``'s bags); looked up in TF at the image's stamp
          (:mod:`nbv_prob_cnn.perception.bag_pairing`).

The message codecs live in :mod:`nbv_prob_cnn.perception.messages` (re-exported here).
Messages are CDR-serialized with the ROS 2 Jazzy type store: ``rclpy.serialization`` reads them,
and its bytes read back here (checked field by field; only the alignment padding bytes, which
rclpy leaves uninitialised, can differ). A frame is an image, its camera_info (same header stamp)
and its pose.

Reading validates the whole bag before yielding the first frame (every message is read,
deserialized and converted, message counts are checked against the bag's own index), so a
corrupt or truncated bag raises :class:`BagError` up front instead of giving a silent partial read.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from nbv_prob_cnn.basics.file_kind import check_kind, sniff
from nbv_prob_cnn.perception.bag_pairing import (
    CAMERA_TOPICS,
    MSG_TF,
    POSE_SOURCES,
    POSE_TOPICS,
    TOPIC_CAMERA_INFO,
    TOPIC_IMAGE,
    TOPIC_POSE,
    TOPIC_TF,
    TOPIC_TF_STATIC,
    Frame,
    StampPairing,
    TfPairing,
    pose_source_of,
    topics_read,
)
from nbv_prob_cnn.perception.depth_camera import Intrinsics
from nbv_prob_cnn.perception.messages import (
    MSG_CAMERA_INFO,
    MSG_IMAGE,
    MSG_TRANSFORM,
    OPTICAL_FRAME,
    WORLD_FRAME,
    camera_info_to_intrinsics,
    depth_to_image_msg,
    image_msg_to_depth,
    intrinsics_to_camera_info,
    pose_to_transform_msg,
    stamp_of,
    transform_msg_to_pose,
    typestore,
)

__all__ = [
    "BagError",
    "BagWarning",
    "BagWriter",
    "Frame",
    "MSG_CAMERA_INFO",
    "MSG_IMAGE",
    "MSG_TF",
    "MSG_TRANSFORM",
    "OPTICAL_FRAME",
    "POSE_SOURCES",
    "WORLD_FRAME",
    "RawMessage",
    "TOPIC_CAMERA_INFO",
    "TOPIC_IMAGE",
    "TOPIC_POSE",
    "TOPIC_TF",
    "TOPIC_TF_STATIC",
    "bag_pose_source",
    "bag_topics",
    "camera_info_to_intrinsics",
    "depth_to_image_msg",
    "image_msg_to_depth",
    "intrinsics_to_camera_info",
    "pose_to_transform_msg",
    "read_frames",
    "read_raw_messages",
    "stamp_of",
    "transform_msg_to_pose",
    "typestore",
]


class BagError(ValueError):
    """A bag that cannot be read: missing, corrupt, truncated or not a depth-camera bag."""


class BagWarning(UserWarning):
    """Messages of a bag that do not form complete frames (skipped)."""


# ----------------------------------------------------------------------------------- writing
class BagWriter:
    """Context manager writing posed depth frames to a new rosbag2 directory (mcap storage).

    Example::

        with BagWriter("run1") as bag:
            bag.write_frame(stamp_ns, depth, intrinsics, pose)

    Args:
        pose_source: ``topic``: each pose on ``/camera/pose`` (``TransformStamped``, the simulated
            bags); ``tf``: on ``/tf`` (a ``TFMessage`` holding the one transform ``world`` -> the
            image's frame, written just before the image), as a robot's recording has it.

    Raises:
        BagError: the path exists already or the bag cannot be created.
        ValueError: another pose source.
    """

    def __init__(self, path: str | Path, pose_source: str = "topic") -> None:
        if pose_source not in POSE_SOURCES:
            raise ValueError(f"pose_source: expected one of {POSE_SOURCES}, got {pose_source!r}")
        self.path = Path(path)
        self.pose_source = pose_source
        self.frames = 0
        self._writer: Any = None
        self._conns: dict[str, Any] = {}

    def open(self) -> BagWriter:
        """Create the bag and its three connections."""
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

        if self.path.exists():
            raise BagError(f"{self.path}: exists already; a bag is never overwritten")
        try:
            self._writer = Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
            self._writer.open()
            store = typestore()
            for topic, msgtype in topics_read(self.pose_source, {}).items():
                self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=store)
        except (WriterError, OSError) as exc:
            raise BagError(f"{self.path}: cannot create the bag ({exc})") from exc
        return self

    def write_frame(
        self,
        stamp_ns: int,
        depth: np.ndarray,
        intrinsics: Intrinsics,
        pose_4x4: np.ndarray,
        encoding: str = "32FC1",
    ) -> None:
        """Write one frame: pose (on ``/tf`` first, or on ``/camera/pose`` last), image and camera
        info, all stamped ``stamp_ns``.

        Raises:
            ValueError: unsupported encoding, bad pose, or image shape not matching the intrinsics.
        """
        if self._writer is None:
            raise BagError(f"{self.path}: bag is not open (use it as a context manager)")
        if np.asarray(depth).shape != intrinsics.shape:
            raise ValueError(f"depth: shape {np.asarray(depth).shape} does not match the intrinsics {intrinsics.shape}")
        store = typestore()
        camera = (
            (TOPIC_IMAGE, MSG_IMAGE, depth_to_image_msg(depth, stamp_ns, encoding, OPTICAL_FRAME)),
            (TOPIC_CAMERA_INFO, MSG_CAMERA_INFO, intrinsics_to_camera_info(intrinsics, stamp_ns, OPTICAL_FRAME)),
        )
        transform = pose_to_transform_msg(pose_4x4, stamp_ns, WORLD_FRAME, OPTICAL_FRAME)
        if self.pose_source == "tf":
            msgs = ((TOPIC_TF, MSG_TF, store.types[MSG_TF](transforms=[transform])), *camera)
        else:
            msgs = (*camera, (TOPIC_POSE, MSG_TRANSFORM, transform))
        for topic, msgtype, msg in msgs:
            self._writer.write(self._conns[topic], int(stamp_ns), store.serialize_cdr(msg, msgtype))
        self.frames += 1

    def close(self) -> None:
        """Finish the bag (index, metadata.yaml)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


# ----------------------------------------------------------------------------------- reading
def _open_reader(path: Path) -> Any:
    from rosbags.rosbag2 import Reader

    if not path.exists():
        raise FileNotFoundError(f"{path}: no such bag")
    found = sniff(path)
    if found.kind not in ("bag", "folder"):  # a folder without metadata.yaml: rosbags says what it misses
        try:
            check_kind(path, "", ("bag",), "a rosbag2 bag (a folder with metadata.yaml, or an .mcap file)")
        except ValueError as exc:
            raise BagError(str(exc)) from None
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises ReaderError, but also struct/yaml/zstd errors on garbage
        raise BagError(f"{path}: not a readable rosbag2 bag ({type(exc).__name__}: {exc})") from exc
    return reader


def _connections(reader: Any, path: Path) -> tuple[str, dict[str, Any]]:
    """The bag's pose source (:func:`~nbv_prob_cnn.perception.bag_pairing.pose_source_of`) and the
    connections of the topics its frames are made of, checked."""
    known = {**CAMERA_TOPICS, **POSE_TOPICS}
    by_topic: dict[str, Any] = {}
    for conn in reader.connections:
        if conn.topic in known:
            if conn.msgtype != known[conn.topic]:
                raise BagError(f"{path}: topic {conn.topic} has type {conn.msgtype}, expected {known[conn.topic]}")
            if conn.topic in by_topic:
                raise BagError(f"{path}: topic {conn.topic} is recorded on more than one connection")
            by_topic[conn.topic] = conn
    pose_source = pose_source_of(by_topic)
    wanted = topics_read(pose_source or "topic", by_topic)
    missing = sorted(set(wanted) - set(by_topic))
    if missing:
        present = sorted({c.topic for c in reader.connections})
        poses = "" if pose_source else f" (the poses: {TOPIC_POSE} or {TOPIC_TF})"
        raise BagError(f"{path}: missing topic(s) {missing}{poses}; the bag has {present}")
    assert pose_source is not None  # else /camera/pose would be missing
    return pose_source, {topic: by_topic[topic] for topic in wanted}


def _frames(
    path: Path,
    conns: dict[str, Any],
    pairing: StampPairing | TfPairing,
    unpaired: str,
    counts: dict[str, int] | None = None,
) -> Iterator[Frame]:
    """One pass over the bag, yielding complete frames; errors become :class:`BagError`.

    ``unpaired``: what to do at the end with messages that never formed a frame:
    ``"warn"`` (:class:`BagWarning`), ``"error"`` (:class:`BagError`) or ``"ignore"``.
    """
    store = typestore()
    reader = _open_reader(path)
    topic_of = {conn.id: topic for topic, conn in conns.items()}
    frames = 0
    try:
        stream = reader.messages(connections=list(conns.values()))
        while True:
            where = f"{path}: after {frames} complete frame(s)"
            try:
                item = next(stream)
            except StopIteration:
                break
            except Exception as exc:
                raise BagError(f"{where}: corrupt or truncated bag ({type(exc).__name__}: {exc})") from exc
            conn, _, raw = item
            topic = topic_of[conn.id]
            if counts is not None:
                counts[topic] = counts.get(topic, 0) + 1
            try:
                msg = store.deserialize_cdr(raw, conn.msgtype)
            except Exception as exc:
                raise BagError(f"{where}: cannot deserialize a {conn.msgtype} message on {topic} ({exc})") from exc
            try:
                done = pairing.add(topic, msg)
            except ValueError as exc:
                raise BagError(f"{where}: {exc}") from exc
            for frame in done:
                frames += 1
                yield frame
    finally:
        reader.close()
    leftovers = pairing.finish()
    if leftovers and unpaired != "ignore":
        text = f"{path}: {leftovers}"
        if unpaired == "error":
            raise BagError(text)
        warnings.warn(text + "; skipped", BagWarning, stacklevel=2)


def bag_pose_source(path: str | Path) -> str:
    """Where a depth-camera bag's poses come from: ``topic`` (``/camera/pose``) or ``tf`` (``/tf``).

    Raises:
        FileNotFoundError: no such path.
        BagError: unreadable bag, or not a depth-camera bag (topics missing or of other types).
    """
    path = Path(path)
    reader = _open_reader(path)
    try:
        return _connections(reader, path)[0]
    finally:
        reader.close()


def read_frames(
    path: str | Path, validate: bool = True, strict: bool = False, fixed_frame: str = WORLD_FRAME
) -> Iterator[Frame]:
    """Posed depth frames of a bag (a rosbag2 directory or a single ``.mcap`` file), in bag order.

    An image and its camera_info pair by header stamp; the pose is the ``/camera/pose`` message of
    that stamp or, in a bag without ``/camera/pose``, the image frame's pose in ``fixed_frame`` by
    ``/tf`` (+ ``/tf_static``) at that stamp (:mod:`~nbv_prob_cnn.perception.bag_pairing`). A frame
    is yielded when all three are there. Messages without partners, and images that TF never
    poses, are skipped with a :class:`BagWarning` (or a :class:`BagError` when ``strict``).

    Args:
        validate: read and convert the whole bag once before returning, so that a corrupt,
            truncated or unsupported bag raises here, before any frame is used (the bag is read
            twice). Without it a corruption raises when reached, naming the number of frames
            already read.
        strict: unpaired messages are an error.
        fixed_frame: the frame the poses are looked up in (``/tf`` bags).

    Raises:
        FileNotFoundError: no such path.
        BagError: unreadable, corrupt or truncated bag, missing topics, wrong message types,
            unsupported image encoding (named), duplicate stamps, invalid transforms.
    """
    path = Path(path)
    reader = _open_reader(path)
    try:
        pose_source, conns = _connections(reader, path)
        expected = {topic: int(conn.msgcount) for topic, conn in conns.items()}
    finally:
        reader.close()

    def pairing() -> StampPairing | TfPairing:
        return StampPairing() if pose_source == "topic" else TfPairing(fixed_frame)

    unpaired = "error" if strict else "warn"
    if validate:
        counts: dict[str, int] = {}
        n_frames = sum(1 for _ in _frames(path, conns, pairing(), unpaired, counts))
        for topic, n_expected in expected.items():
            if n_expected and counts.get(topic, 0) != n_expected:
                raise BagError(
                    f"{path}: truncated bag: {counts.get(topic, 0)} {topic} message(s) readable, "
                    f"the bag index lists {n_expected} ({n_frames} complete frame(s) before the damage)"
                )
        unpaired = "ignore"  # already reported
    return _frames(path, conns, pairing(), unpaired)


# ------------------------------------------------------------------------- raw messages
@dataclass(frozen=True)
class RawMessage:
    """One serialized (CDR) message of a bag, as recorded."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


def bag_topics(path: str | Path) -> dict[str, tuple[str, int]]:
    """``{topic: (message type, message count from the bag's index)}`` of any rosbag2 bag.

    Raises:
        FileNotFoundError: no such path.
        BagError: unreadable bag, or a topic recorded with two different types.
    """
    path = Path(path)
    reader = _open_reader(path)
    try:
        topics: dict[str, tuple[str, int]] = {}
        for conn in reader.connections:
            msgtype, count = topics.get(conn.topic, (conn.msgtype, 0))
            if msgtype != conn.msgtype:
                raise BagError(f"{path}: topic {conn.topic} is recorded with types {msgtype} and {conn.msgtype}")
            topics[conn.topic] = (msgtype, count + int(conn.msgcount))
        return topics
    finally:
        reader.close()


def _raw_pass(path: Path, topics: set[str] | None, deserialize: bool) -> Iterator[RawMessage]:
    store = typestore()
    reader = _open_reader(path)
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if not conns:
            # rosbags reads every connection when given none: a filter that matches nothing reads nothing
            return
        stream = reader.messages(connections=conns)
        read = 0
        while True:
            try:
                conn, log_time, data = next(stream)
            except StopIteration:
                break
            except Exception as exc:
                raise BagError(
                    f"{path}: corrupt or truncated bag after {read} message(s) ({type(exc).__name__}: {exc})"
                ) from exc
            if deserialize and conn.msgtype in store.types:
                try:
                    store.deserialize_cdr(data, conn.msgtype)
                except Exception as exc:
                    raise BagError(
                        f"{path}: message {read} on {conn.topic} is not a valid {conn.msgtype} ({exc})"
                    ) from exc
            read += 1
            yield RawMessage(conn.topic, conn.msgtype, int(log_time), bytes(data))
    finally:
        reader.close()


def read_raw_messages(
    path: str | Path, topics: Iterable[str] | None = None, validate: bool = True
) -> Iterator[RawMessage]:
    """The serialized messages of any rosbag2 bag (or of ``topics``), in log-time order (for replay).

    Args:
        validate: read the whole bag once before returning: every message must be readable and
            (for the ROS 2 Jazzy standard types) deserialize, and the number read per topic must
            match the bag's index, so a corrupt or truncated bag raises here, before any message
            is used.

    Raises:
        FileNotFoundError: no such path.
        BagError: unreadable, corrupt or truncated bag.
    """
    path = Path(path)
    selected = None if topics is None else set(topics)
    if validate:
        expected = {t: n for t, (_, n) in bag_topics(path).items() if selected is None or t in selected}
        counts: dict[str, int] = {}
        for msg in _raw_pass(path, selected, deserialize=True):
            counts[msg.topic] = counts.get(msg.topic, 0) + 1
        for topic, n_expected in expected.items():
            if n_expected and counts.get(topic, 0) != n_expected:
                raise BagError(
                    f"{path}: truncated bag: {counts.get(topic, 0)} {topic} message(s) readable, "
                    f"the bag index lists {n_expected}"
                )
    return _raw_pass(path, selected, deserialize=False)
