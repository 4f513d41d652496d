"""Conversions between our messages and numpy (no node needed; testable without a graph).

Grids travel flattened x fastest, then y, then z (docs/method.md#grids). Large arrays are assigned as
``array.array`` and read with ``np.frombuffer`` (assigning numpy arrays to message fields is
slow in rclpy).
"""

from __future__ import annotations

import array
import math
import zlib

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose, PoseStamped, TransformStamped
from nbv_prob_cnn_msgs.msg import CompressedVoxelGrid, ProbabilityGrid, VoxelGrid

from nbv_prob_cnn.basics.camera import quaternion_from_matrix
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.perception.messages import stamp_parts

#: Largest grid accepted from the wire (cells); bigger requests are refused with a reason. A room:
#: the 7-Scenes kitchen at 1.16 cm over its bounding box is 52.5 M cells (52 MB as a VoxelGrid).
MAX_GRID_CELLS = 2**26  # 67 M cells

#: The formats of :class:`CompressedVoxelGrid` this package writes and reads.
GRID_FORMATS = ("zlib",)
#: zlib level of the compressed grid: 1 compresses a half-explored 256 × 256 × 192 grid (12.6 MB)
#: 27-fold in about 25 ms (docs/ros.md, "Room-sized grids").
ZLIB_LEVEL = 1


def time_msg(stamp_ns: int) -> Time:
    """A ``builtin_interfaces/Time`` of a stamp in nanoseconds (the inverse is ``messages.stamp_ns``)."""
    sec, nanosec = stamp_parts(stamp_ns)
    return Time(sec=sec, nanosec=nanosec)


def _check_identity_orientation(pose: Pose, what: str) -> None:
    q = pose.orientation
    if not (abs(q.x) < 1e-6 and abs(q.y) < 1e-6 and abs(q.z) < 1e-6 and abs(abs(q.w) - 1) < 1e-6):
        raise ValueError(f"{what}: only axis-aligned grids are supported (origin orientation must be identity)")


def geometry_of(msg: VoxelGrid | ProbabilityGrid | CompressedVoxelGrid) -> GridGeometry:
    """Grid geometry of a grid message (``size_z == 1`` means a 2D grid).

    Raises:
        ValueError: zero or huge sizes, bad resolution, rotated origin.
    """
    sizes = (int(msg.size_x), int(msg.size_y), int(msg.size_z))
    if min(sizes) < 1:
        raise ValueError(f"grid: sizes must be positive, got {sizes}")
    if math.prod(sizes) > MAX_GRID_CELLS:
        raise ValueError(f"grid: {math.prod(sizes)} cells exceed the limit of {MAX_GRID_CELLS}")
    _check_identity_orientation(msg.origin, "grid.origin")
    p = msg.origin.position
    shape = sizes[:2] if sizes[2] == 1 else sizes
    return GridGeometry((p.x, p.y, p.z), float(msg.resolution), shape)


def _fill_geometry(msg, geometry: GridGeometry, frame_id: str, stamp) -> None:
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    msg.origin.position.x, msg.origin.position.y, msg.origin.position.z = (float(v) for v in geometry.origin)
    msg.origin.orientation.w = 1.0
    msg.resolution = float(geometry.resolution)
    shape3 = tuple(geometry.shape) + (1,) * (3 - geometry.dims)
    msg.size_x, msg.size_y, msg.size_z = (int(n) for n in shape3)


def grid_to_msg(state: np.ndarray, geometry: GridGeometry, frame_id: str = "world", stamp=None) -> VoxelGrid:
    """A ternary ``int8`` grid ``[x, y(, z)]`` as a :class:`VoxelGrid` message."""
    msg = VoxelGrid()
    _fill_geometry(msg, geometry, frame_id, stamp)
    msg.data = array.array("b", np.asarray(state, dtype=np.int8).ravel(order="F").tobytes())
    return msg


def probability_to_msg(
    prob: np.ndarray, geometry: GridGeometry, frame_id: str = "world", stamp=None
) -> ProbabilityGrid:
    """A probability map as a :class:`ProbabilityGrid` message."""
    msg = ProbabilityGrid()
    _fill_geometry(msg, geometry, frame_id, stamp)
    msg.data = array.array("f", np.asarray(prob, dtype=np.float32).ravel(order="F").tobytes())
    return msg


def _same_geometry(msg_type, msg):
    """A ``msg_type`` message with the header, origin, resolution and sizes of grid message ``msg``."""
    return msg_type(
        header=msg.header, origin=msg.origin, resolution=msg.resolution,
        size_x=msg.size_x, size_y=msg.size_y, size_z=msg.size_z,
    )  # fmt: skip


def compress_grid_msg(msg: VoxelGrid, level: int = ZLIB_LEVEL) -> CompressedVoxelGrid:
    """The :class:`CompressedVoxelGrid` (format ``zlib``) of a :class:`VoxelGrid`: the same header,
    origin, resolution and sizes, the data compressed as one zlib stream."""
    out = _same_geometry(CompressedVoxelGrid, msg)
    out.format = "zlib"
    out.data = array.array("B", zlib.compress(_data_array(msg, np.int8).tobytes(), level))
    return out


def decompress_grid_msg(msg: CompressedVoxelGrid) -> VoxelGrid:
    """The :class:`VoxelGrid` a :class:`CompressedVoxelGrid` carries.

    Raises:
        ValueError: a format other than ``zlib``, bad sizes (:func:`geometry_of`: checked before
            anything is decompressed), a stream that is not zlib, or data of another length than
            the sizes say.
    """
    if msg.format not in GRID_FORMATS:
        raise ValueError(f"compressed grid: format {msg.format!r} is not one of {list(GRID_FORMATS)}")
    cells = math.prod(geometry_of(msg).shape)
    inflate = zlib.decompressobj()
    try:  # at most one byte more than the sizes say: a stream that inflates further is refused unread
        data = inflate.decompress(bytes(msg.data), cells + 1)
    except zlib.error as exc:
        raise ValueError(f"compressed grid: data is not a zlib stream ({exc})") from exc
    if len(data) > cells or (len(data) == cells and inflate.unconsumed_tail):
        raise ValueError(f"compressed grid: data inflates to more than size_x*size_y*size_z = {cells} cells")
    if len(data) < cells:
        raise ValueError(f"compressed grid: data inflates to {len(data)} cells but size_x*size_y*size_z = {cells}")
    if not inflate.eof:
        raise ValueError("compressed grid: the zlib stream is truncated (no end of stream)")
    out = _same_geometry(VoxelGrid, msg)
    out.data = array.array("b", data)
    return out


def _data_array(msg, dtype) -> np.ndarray:
    data = msg.data
    if isinstance(data, array.array | bytes | bytearray | memoryview):
        return np.frombuffer(data, dtype=dtype)
    return np.asarray(data, dtype=dtype)


def msg_to_grid(msg: VoxelGrid) -> tuple[np.ndarray, GridGeometry]:
    """The ``int8`` grid ``[x, y(, z)]`` and geometry of a :class:`VoxelGrid`.

    Raises:
        ValueError: data length does not match the sizes, or values outside {-1, 0, 1}.
    """
    geometry = geometry_of(msg)
    data = _data_array(msg, np.int8)
    if data.size != math.prod(geometry.shape):
        raise ValueError(f"grid: data has {data.size} cells but size_x*size_y*size_z = {math.prod(geometry.shape)}")
    if data.size and (data.min() < -1 or data.max() > 1):
        raise ValueError("grid: data values must be -1 (unknown), 0 (empty) or 1 (occupied)")
    return np.ascontiguousarray(data.reshape(geometry.shape, order="F")), geometry


def msg_to_probability(msg: ProbabilityGrid) -> tuple[np.ndarray, GridGeometry]:
    """The ``float32`` probability map and geometry of a :class:`ProbabilityGrid`."""
    geometry = geometry_of(msg)
    data = _data_array(msg, np.float32)
    if data.size != math.prod(geometry.shape):
        raise ValueError(f"probability: data has {data.size} cells, expected {math.prod(geometry.shape)}")
    return np.ascontiguousarray(data.reshape(geometry.shape, order="F")), geometry


def pose_to_arrays(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) and unit quaternion (x, y, z, w) of a pose.

    Raises:
        ValueError: NaN/inf components or a zero quaternion.
    """
    p, q = pose.position, pose.orientation
    position = np.array([p.x, p.y, p.z], dtype=np.float64)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    if not np.all(np.isfinite(position)):
        raise ValueError(f"pose: position has NaN or infinite components {position.tolist()}")
    norm = np.linalg.norm(quat)
    if not np.all(np.isfinite(quat)) or norm < 1e-6:
        raise ValueError(f"pose: orientation must be a finite non-zero quaternion, got {quat.tolist()}")
    return position, quat / norm


def arrays_to_pose_stamped(position: np.ndarray, quat: np.ndarray, frame_id: str, stamp=None) -> PoseStamped:
    """A :class:`PoseStamped` from a position and a quaternion (x, y, z, w)."""
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in quat)
    return msg


def transform_stamped_msg(matrix: np.ndarray, stamp_ns: int, parent: str, child: str) -> TransformStamped:
    """A :class:`TransformStamped` (as on ``/tf``: the pose of ``child`` in ``parent``) of a 4×4 rigid
    transform."""
    msg = TransformStamped()
    msg.header.frame_id = parent
    msg.header.stamp = time_msg(stamp_ns)
    msg.child_frame_id = child
    t = msg.transform.translation
    t.x, t.y, t.z = (float(v) for v in np.asarray(matrix)[:3, 3])
    r = msg.transform.rotation
    r.x, r.y, r.z, r.w = (float(v) for v in quaternion_from_matrix(np.asarray(matrix)[:3, :3]))
    return msg
