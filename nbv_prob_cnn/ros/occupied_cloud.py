"""The occupied cells of a ternary grid as a ``sensor_msgs/PointCloud2`` of their centres (for RViz),
and the integrator's throttled sending of them (:class:`OccupiedCloudOutput`)."""

from __future__ import annotations

import threading
import time

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.perception.surfaces import occupied_centres
from nbv_prob_cnn.ros.conversions import time_msg
from nbv_prob_cnn.ros.latest_sent import LatestSent

__all__ = ["OccupiedCloudOutput", "occupied_cloud_msg"]


def occupied_cloud_msg(grid: np.ndarray, origin_m, voxel_size_m: float, frame_id: str, stamp: Time) -> PointCloud2:
    """An unorganised ``PointCloud2`` (``x y z`` float32, world metres) of the occupied cell centres."""
    xyz = np.ascontiguousarray(occupied_centres(grid, np.asarray(origin_m), voxel_size_m), dtype="<f4")
    fields = [PointField(name=axis, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, axis in enumerate("xyz")]
    return PointCloud2(
        header=Header(stamp=stamp, frame_id=frame_id), height=1, width=len(xyz), fields=fields, is_bigendian=False,
        point_step=12, row_step=12 * len(xyz), data=xyz.tobytes(), is_dense=True,
    )  # fmt: skip


class OccupiedCloudOutput:
    """The occupied cells of the latest grid on ``publisher``, at most ``rate_hz`` times a second
    and only while someone subscribes: when the grid is new since the last cloud, or a subscriber
    joined since (a volatile one, such as RViz opened later, gets the current cloud without
    waiting for the next frame). The node's worker (new grids) and a timer both call :meth:`send`."""

    def __init__(self, publisher, rate_hz: float, geometry: GridGeometry, frame_id: str) -> None:
        self._publisher = publisher
        self._rate_hz = rate_hz
        self._geometry = geometry
        self._frame_id = frame_id
        self._lock = threading.Lock()
        self._latest: tuple[np.ndarray, int] | None = None  # the latest grid and its stamp
        self._sent = LatestSent()  # the (grid, stamp) of the last cloud sent, and the subscribers then
        self._next = 0.0  # time.monotonic() before which no cloud goes out

    def update(self, grid: np.ndarray, stamp_ns: int) -> None:
        """Make ``grid`` (stamped ``stamp_ns``) the one the next cloud shows, and send it when due."""
        with self._lock:
            self._latest = (grid, stamp_ns)
        self.send()

    def send(self) -> None:
        """The latest grid's cloud, when due and not throttled (then a later call sends it)."""
        if self._rate_hz <= 0:
            return
        with self._lock:
            latest, subscribers = self._latest, self._publisher.get_subscription_count()
            if not self._sent.due(latest, subscribers) or time.monotonic() < self._next:
                return
            assert latest is not None
            grid, stamp_ns = latest
            self._next = time.monotonic() + 1.0 / self._rate_hz
            self._sent.sent(latest, subscribers)
            self._publisher.publish(
                occupied_cloud_msg(grid, self._geometry.origin, self._geometry.resolution, self._frame_id,
                                   time_msg(stamp_ns))
            )  # fmt: skip
