"""Camera model: sensor parameters per data set, candidate orientations and frustum tests
(docs/method.md: sensor, candidate views, parameters).

Conventions:
    * 3D: the camera optical frame follows REP-103 (x right, y down, z forward); an
      orientation is a unit quaternion ``(x, y, z, w)`` rotating optical-frame vectors into
      grid/world axes. The grid's +z axis is "up".
    * 2D: the camera looks along its +x axis in the plane; an orientation is a yaw angle in
      radians (its quaternion is the rotation about +z).
"""

from __future__ import annotations

import math

import numpy as np

from nbv_prob_cnn.basics.datasets import DATASET_SPECS, DatasetSpec, dataset_spec
from nbv_prob_cnn.basics.sensor import Sensor as Sensor  # re-exported

#: The data sets' parameters now live in :mod:`nbv_prob_cnn.basics.datasets`; these names are kept for callers.
DatasetDefaults = DatasetSpec
DATASETS: dict[str, DatasetSpec] = DATASET_SPECS


def dataset_defaults(name: str) -> DatasetSpec:
    """Look up the defaults of a data set by name (``2d``, ``3du``, ``3dt``); see :func:`dataset_spec`."""
    return dataset_spec(name)


def quaternion_from_matrix(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` of a 3×3 rotation matrix."""
    m = np.asarray(rot, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    quat = np.array(q)
    quat /= np.linalg.norm(quat)
    return quat if quat[3] >= 0 else -quat


def unit_quaternions(quats: np.ndarray, tiny: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Each row of ``(N, 4)`` quaternions scaled to unit length, and whether it could be.

    Rows are divided by their largest absolute component before the norm is taken, so huge finite
    components (``1e200``) do not overflow and tiny ones do not underflow. A row with a NaN or
    infinite component, or whose norm is below ``tiny``, is not valid; its output row is 0.
    """
    q = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
    finite = np.all(np.isfinite(q), axis=1)
    safe = np.where(finite[:, None], q, 0.0)
    scale = np.max(np.abs(safe), axis=1)
    scaled = safe / np.where(scale > 0, scale, 1.0)[:, None]
    norm = np.linalg.norm(scaled, axis=1)
    ok = finite & (scale > 0) & (norm * scale >= tiny)
    unit = np.zeros_like(q)
    unit[ok] = scaled[ok] / norm[ok, None]
    return unit, ok


def matrix_from_quaternion(quat: np.ndarray) -> np.ndarray:
    """3×3 rotation matrix of a quaternion ``(x, y, z, w)`` (normalised first).

    Raises:
        ValueError: NaN/inf components or a (near) zero quaternion.
    """
    q = np.asarray(quat, dtype=np.float64).reshape(4)
    unit, ok = unit_quaternions(q[None])
    if not ok[0]:
        raise ValueError(f"orientation: expected a finite non-zero quaternion (x, y, z, w), got {q.tolist()}")
    x, y, z, w = unit[0]
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Quaternion ``(x, y, z, w)`` of a rotation by ``yaw`` radians about +z."""
    return np.array([0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)])


def look_rotation(forward: np.ndarray, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation matrix (columns = optical x, y, z in grid axes) of a camera looking along
    ``forward``, with image "up" towards grid +z (grid +x when looking straight up/down),
    then rolled by ``roll_deg`` about the optical axis."""
    z_axis = np.asarray(forward, dtype=np.float64)
    z_axis = z_axis / np.linalg.norm(z_axis)
    up = np.array([0.0, 0.0, 1.0])
    if abs(z_axis @ up) > 0.999:
        up = np.array([1.0, 0.0, 0.0])
    x_axis = np.cross(z_axis, up)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    roll = math.radians(roll_deg)
    c, s = math.cos(roll), math.sin(roll)
    x_rolled = c * x_axis + s * y_axis
    y_rolled = -s * x_axis + c * y_axis
    return np.stack([x_rolled, y_rolled, z_axis], axis=1)


def view_directions_3d() -> np.ndarray:
    """The 26 unit directions of a 3×3×3 neighbourhood, in a fixed order: elevation −45°,
    0°, +45° (azimuth 0°, 45°, …, 315° each), then straight up, then straight down."""
    dirs = []
    for elevation in (-45.0, 0.0, 45.0):
        for azimuth in range(0, 360, 45):
            el, az = math.radians(elevation), math.radians(azimuth)
            dirs.append([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    dirs += [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]
    return np.array(dirs)


def orientations(dims: int) -> np.ndarray:
    """Candidate orientations of docs/method.md#candidate-views-and-view-gain.

    Returns:
        2D: ``(60,)`` yaw angles in radians, every 6° from 0.
        3D: ``(52, 4)`` quaternions ``(x, y, z, w)``: each of :func:`view_directions_3d`
        with roll 0° then roll 90°.
    """
    if dims == 2:
        return np.deg2rad(np.arange(0, 360, 6, dtype=np.float64))
    if dims == 3:
        quats = [quaternion_from_matrix(look_rotation(d, roll)) for d in view_directions_3d() for roll in (0.0, 90.0)]
        return np.array(quats)
    raise ValueError(f"dims: expected 2 or 3, got {dims}")


def optical_axis(orientation: np.ndarray | float, dims: int) -> np.ndarray:
    """Viewing direction (unit vector in grid axes) of one orientation."""
    if dims == 2:
        yaw = float(orientation)
        return np.array([math.cos(yaw), math.sin(yaw)])
    return matrix_from_quaternion(np.asarray(orientation))[:, 2]


def in_frustum(
    directions: np.ndarray, orientations_: np.ndarray, hfov_deg: float, vfov_deg: float | None = None
) -> np.ndarray:
    """Which directions lie inside which view frustum.

    Args:
        directions: ``(R, dims)`` unit vectors in grid axes.
        orientations_: ``(V,)`` yaws (2D) or ``(V, 4)`` quaternions (3D).
        hfov_deg, vfov_deg: full fields of view; ``vfov_deg`` is required in 3D.

    Returns:
        ``(R, V)`` bool: in 2D ``|angle to the optical axis| <= HFOV/2``; in 3D the direction
        is in front of the camera and ``|atan(x/z)| <= HFOV/2`` and ``|atan(y/z)| <= VFOV/2``
        in the optical frame (a pinhole pyramid). A small tolerance (1e-9 rad) keeps
        directions exactly on the boundary inside.
    """
    directions = np.asarray(directions, dtype=np.float64)
    dims = directions.shape[1]
    half_h = math.radians(hfov_deg) / 2.0 + 1e-9
    if dims == 2:
        yaws = np.asarray(orientations_, dtype=np.float64).reshape(-1)
        ray_angle = np.arctan2(directions[:, 1], directions[:, 0])
        diff = np.angle(np.exp(1j * (ray_angle[:, None] - yaws[None, :])))
        return np.abs(diff) <= half_h
    if vfov_deg is None:
        raise ValueError("vfov_deg: required for 3D frusta")
    half_v = math.radians(vfov_deg) / 2.0 + 1e-9
    quats = np.asarray(orientations_, dtype=np.float64).reshape(-1, 4)
    rots = np.stack([matrix_from_quaternion(q) for q in quats])  # (V, 3, 3)
    cam = np.einsum("vji,rj->rvi", rots, directions)  # R^T d for every view: (R, V, 3)
    x, y, z = cam[..., 0], cam[..., 1], cam[..., 2]
    front = z > 1e-12
    zs = np.where(front, z, 1.0)
    return front & (np.abs(np.arctan(x / zs)) <= half_h) & (np.abs(np.arctan(y / zs)) <= half_v)
