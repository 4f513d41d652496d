"""The occupied cells of a ternary grid as a ``sensor_msgs/PointCloud2`` of their centres (for RViz)."""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from nbv_prob_cnn.perception.surfaces import occupied_centres

__all__ = ["occupied_cloud_msg"]


def occupied_cloud_msg(grid: np.ndarray, origin_m, voxel_size_m: float, frame_id: str, stamp: Time) -> PointCloud2:
    """An unorganised ``PointCloud2`` (``x y z`` float32, world metres) of the occupied cell centres."""
    xyz = np.ascontiguousarray(occupied_centres(grid, np.asarray(origin_m), voxel_size_m), dtype="<f4")
    fields = [PointField(name=axis, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, axis in enumerate("xyz")]
    return PointCloud2(
        header=Header(stamp=stamp, frame_id=frame_id), height=1, width=len(xyz), fields=fields, is_bigendian=False,
        point_step=12, row_step=12 * len(xyz), data=xyz.tobytes(), is_dense=True,
    )  # fmt: skip
