"""A TF buffer without rclpy: the transform tree of ``/tf`` and ``/tf_static`` with chained,
time-interpolated lookups, for where ``tf2_ros`` cannot be imported (the ROS wheels of this
environment have no tf2). :mod:`nbv_prob_cnn.ros.tf_listener` fills it from the topics.

Frames form a tree as in tf2: each child frame has one parent (a transform ``parent -> child``
is the pose of the child in the parent, ``geometry_msgs/TransformStamped`` with
``header.frame_id`` = parent and ``child_frame_id`` = child). Dynamic transforms keep a history of
``cache_time_s`` (tf2's default 10 s) and are interpolated between the two samples around the
requested stamp; static ones hold at every stamp.

The rigid-body maths is pytransform3d's (:class:`~pytransform3d.transform_manager.TemporalTransformManager`
composes the chain). Interpolation is tf2's: the translation linearly, the rotation by spherical
linear interpolation along the shorter arc (pytransform3d's ``quaternion_slerp``), evaluated for
the two samples around the stamp only, so a lookup costs the same with a full 10 s history of a
100 Hz stream as with two samples.

A failed lookup raises a :class:`TransformError` naming what is missing: the frame that was
never received (:class:`FrameNotFoundError`), the two trees that do not meet
(:class:`NotConnectedError`) or the transform whose history does not cover the stamp and by how
much (:class:`ExtrapolationError`).
"""

from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass

import numpy as np
from pytransform3d.rotations import matrix_from_quaternion, quaternion_slerp
from pytransform3d.transform_manager import StaticTransform, TemporalTransformManager, TimeVaryingTransform
from pytransform3d.transformations import transform_from_pq

#: tf2's default history of a dynamic transform [s].
DEFAULT_CACHE_TIME_S = 10.0
_NS = 1_000_000_000


class TransformError(LookupError):
    """A lookup that cannot be answered; ``reason`` names the kind (a diagnostics key)."""

    reason = "transform_error"


class FrameNotFoundError(TransformError):
    """A frame that no transform names (yet)."""

    reason = "unknown_frame"


class NotConnectedError(TransformError):
    """Both frames are known but lie in different trees."""

    reason = "not_connected"


class ExtrapolationError(TransformError):
    """A transform on the chain has no data around the requested stamp."""

    reason = "extrapolation"


def normalize_frame(frame: str) -> str:
    """tf2's frame names carry no leading slash (``/world`` is ``world``)."""
    return frame.lstrip("/")


def pq_from_translation_quaternion(translation, quaternion_xyzw) -> np.ndarray:
    """pytransform3d's position-quaternion ``(x, y, z, qw, qx, qy, qz)`` of a translation and a ROS
    quaternion ``(x, y, z, w)``, normalised.

    Raises:
        ValueError: not 3 + 4 numbers, NaN/inf components or a zero quaternion.
    """
    # plain floats: this runs for every transform of every /tf message (thousands a second)
    t = [float(v) for v in np.asarray(translation, dtype=np.float64).reshape(3)]
    q = [float(v) for v in np.asarray(quaternion_xyzw, dtype=np.float64).reshape(4)]
    if not all(math.isfinite(v) for v in (*t, *q)):
        raise ValueError(f"transform: NaN or infinite components (translation {t}, rotation {q})")
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if norm < 1e-9:
        raise ValueError(f"transform: zero quaternion {q}")
    x, y, z, w = (v / norm for v in q)
    return np.array([t[0], t[1], t[2], w, x, y, z])


def matrix_from_translation_quaternion(translation, quaternion_xyzw) -> np.ndarray:
    """4×4 matrix of a translation (3,) and a ROS quaternion ``(x, y, z, w)``.

    Raises:
        ValueError: as :func:`pq_from_translation_quaternion`.
    """
    return transform_from_pq(pq_from_translation_quaternion(translation, quaternion_xyzw))


def _seconds(stamp_ns: int) -> str:
    return f"{stamp_ns / _NS:.6f} s"


class _History(TimeVaryingTransform):
    """The samples of one dynamic transform, sorted by stamp (ns), pruned to the cache time."""

    def __init__(self, cache_ns: int) -> None:
        self.cache_ns = cache_ns
        self.stamps: list[int] = []
        self.pqs: list[np.ndarray] = []  # pytransform3d order: x, y, z, qw, qx, qy, qz

    def add(self, stamp_ns: int, pq: np.ndarray) -> None:
        i = bisect.bisect_left(self.stamps, stamp_ns)
        if i < len(self.stamps) and self.stamps[i] == stamp_ns:
            self.pqs[i] = pq  # a repeated stamp replaces the sample (as tf2)
        else:
            self.stamps.insert(i, stamp_ns)
            self.pqs.insert(i, pq)
        keep = bisect.bisect_left(self.stamps, self.stamps[-1] - self.cache_ns)
        del self.stamps[:keep], self.pqs[:keep]

    @property
    def oldest(self) -> int:
        return self.stamps[0]

    @property
    def newest(self) -> int:
        return self.stamps[-1]

    def as_matrix(self, query_time):
        """The 4×4 pose at ``query_time`` (ns; a scalar, or an array of stamps for an array of
        poses), interpolated as tf2 does between the samples around it (clamped to the history:
        :meth:`TfBuffer.lookup` refuses stamps outside it before asking)."""
        times = np.asarray(query_time)
        if times.ndim:
            poses = [self.as_matrix(t) for t in times.ravel()]
            return np.array(poses).reshape(*times.shape, 4, 4)
        stamp = int(times)
        if stamp <= self.stamps[0]:
            position, rotation = self.pqs[0][:3], self.pqs[0][3:]
        elif stamp >= self.stamps[-1]:
            position, rotation = self.pqs[-1][:3], self.pqs[-1][3:]
        else:  # strictly inside: two samples around the stamp
            later = bisect.bisect_right(self.stamps, stamp)
            earlier = later - 1
            before, after = self.pqs[earlier], self.pqs[later]
            fraction = (stamp - self.stamps[earlier]) / (self.stamps[later] - self.stamps[earlier])
            position = (1.0 - fraction) * before[:3] + fraction * after[:3]
            rotation = quaternion_slerp(before[3:], after[3:], fraction, shortest_path=True)
        matrix = np.eye(4)
        matrix[:3, :3] = matrix_from_quaternion(rotation)
        matrix[:3, 3] = position
        return matrix

    def check_transforms(self):
        return self  # every sample was checked and normalised when it was added


@dataclass
class _Edge:
    parent: str
    static: bool
    transform: TimeVaryingTransform


class TfBuffer:
    """Transforms between frames at a stamp, from the ``/tf`` and ``/tf_static`` samples given to
    :meth:`set_transform`. Thread-safe."""

    def __init__(self, cache_time_s: float = DEFAULT_CACHE_TIME_S) -> None:
        if not cache_time_s > 0:
            raise ValueError(f"cache_time_s: must be positive, got {cache_time_s!r}")
        self.cache_ns = round(cache_time_s * _NS)
        self._edges: dict[str, _Edge] = {}  # child -> its parent and its transform
        self._manager = TemporalTransformManager(check=False)
        self._lock = threading.Lock()

    # ---------------------------------------------------------------- filling
    def set_transform(
        self, parent: str, child: str, stamp_ns: int, translation, quaternion_xyzw, static: bool = False
    ) -> None:
        """Add the pose of ``child`` in ``parent`` at ``stamp_ns`` (a static one holds at every stamp
        and replaces any earlier one). A child given a new parent is moved there (as tf2).

        Raises:
            ValueError: empty or equal frame names, a negative stamp, NaN/inf or a zero quaternion.
        """
        parent, child = normalize_frame(parent), normalize_frame(child)
        if not parent or not child:
            raise ValueError(f"transform {parent!r} -> {child!r}: frame names must not be empty")
        if parent == child:
            raise ValueError(f"transform {parent!r} -> {child!r}: a frame cannot be its own parent")
        if stamp_ns < 0:
            raise ValueError(f"transform {parent!r} -> {child!r}: negative stamp {stamp_ns} ns")
        pq = pq_from_translation_quaternion(translation, quaternion_xyzw)
        fixed = StaticTransform(transform_from_pq(pq)) if static else None
        with self._lock:
            edge = self._edges.get(child)
            if (edge is None or edge.parent != parent) and child in self._ancestors(parent):
                raise ValueError(f"transform {parent!r} -> {child!r}: {child!r} is an ancestor of {parent!r}")
            if edge is not None and (edge.parent != parent or edge.static != static):
                self._manager.remove_transform(child, edge.parent)
                edge = None
            if edge is None or fixed is not None:  # a new edge, or a static one replaced
                transform: TimeVaryingTransform = fixed if fixed is not None else _History(self.cache_ns)
                edge = _Edge(parent, static, transform)
                self._edges[child] = edge
                self._manager.add_transform(child, parent, transform)
            if fixed is None:
                assert isinstance(edge.transform, _History)
                edge.transform.add(int(stamp_ns), pq)

    def clear(self) -> None:
        """Forget every transform (e.g. after a jump back in time)."""
        with self._lock:
            self._edges.clear()
            self._manager = TemporalTransformManager(check=False)

    # ---------------------------------------------------------------- queries
    def frames(self) -> list[str]:
        """Every frame named so far."""
        with self._lock:
            return sorted(set(self._edges) | {edge.parent for edge in self._edges.values()})

    def _ancestors(self, frame: str) -> list[str]:
        """``frame``, its parent, ... up to its tree's root."""
        chain = [frame]
        while chain[-1] in self._edges:
            chain.append(self._edges[chain[-1]].parent)
        return chain

    def _path_edges(self, target: str, source: str) -> list[tuple[str, _Edge]]:
        """The edges (child, edge) between ``source`` and ``target``, checked to exist."""
        known = set(self._edges) | {edge.parent for edge in self._edges.values()}
        for role, frame in (("source", source), ("target", target)):
            if frame not in known:
                hint = f"; known frames: {', '.join(sorted(known))}" if known else "; no transform received yet"
                raise FrameNotFoundError(f"{role} frame {frame!r} does not exist{hint}")
        up_source, up_target = self._ancestors(source), self._ancestors(target)
        if up_source[-1] != up_target[-1]:
            raise NotConnectedError(
                f"frames {source!r} and {target!r} are not connected: {source!r} is in the tree of "
                f"{up_source[-1]!r}, {target!r} in the tree of {up_target[-1]!r}"
            )
        common = next(frame for frame in up_source if frame in set(up_target))
        below = up_source[: up_source.index(common)] + up_target[: up_target.index(common)]
        return [(child, self._edges[child]) for child in below]

    def _stamp_for(self, target: str, source: str, edges: list[tuple[str, _Edge]], stamp_ns: int | None) -> int:
        """The stamp to evaluate at: ``stamp_ns``, checked against every dynamic transform's
        history; ``None`` = the newest stamp all of them cover (tf2's time 0)."""
        dynamic = [(child, edge) for child, edge in edges if not edge.static]
        if not dynamic:
            return 0 if stamp_ns is None else int(stamp_ns)
        histories = [(child, edge.parent, edge.transform) for child, edge in dynamic]
        if stamp_ns is None:
            stamp_ns = min(h.newest for _, _, h in histories)  # type: ignore[attr-defined]
        for child, parent, history in histories:
            assert isinstance(history, _History)
            if history.oldest <= stamp_ns <= history.newest:
                continue
            if stamp_ns > history.newest:
                gap = f"{(stamp_ns - history.newest) / _NS:.3f} s after its newest sample ({_seconds(history.newest)})"
            else:
                gap = f"{(history.oldest - stamp_ns) / _NS:.3f} s before its oldest sample ({_seconds(history.oldest)})"
            raise ExtrapolationError(
                f"cannot transform {source!r} into {target!r} at {_seconds(stamp_ns)}: the transform "
                f"{parent!r} -> {child!r} has data from {_seconds(history.oldest)} to "
                f"{_seconds(history.newest)}; the request is {gap}"
            )
        return int(stamp_ns)

    def lookup(self, target_frame: str, source_frame: str, stamp_ns: int | None = None) -> tuple[np.ndarray, int]:
        """The pose of ``source_frame`` in ``target_frame`` (the 4×4 matrix that maps points in
        the source frame into the target frame, as tf2's ``lookup_transform(target, source, t)``)
        at ``stamp_ns``, or at the newest stamp the chain covers when ``None``; returns the matrix
        and the stamp it holds at.

        Raises:
            FrameNotFoundError, NotConnectedError, ExtrapolationError (all :class:`TransformError`).
        """
        target, source = normalize_frame(target_frame), normalize_frame(source_frame)
        with self._lock:
            edges = self._path_edges(target, source)
            stamp = self._stamp_for(target, source, edges, stamp_ns)
            matrix = self._manager.get_transform_at_time(source, target, np.int64(stamp))
        return np.asarray(matrix, dtype=np.float64).reshape(4, 4), stamp

    def can_transform(self, target_frame: str, source_frame: str, stamp_ns: int | None = None) -> bool:
        """Whether :meth:`lookup` would succeed."""
        try:
            self.lookup(target_frame, source_frame, stamp_ns)
        except TransformError:
            return False
        return True
