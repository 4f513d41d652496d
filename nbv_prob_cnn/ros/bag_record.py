"""``bag_record``: record the depth-camera topics to a rosbag2 (mcap) with ``rosbags``.

There is no ``ros2 bag record`` here; this node records what :mod:`~nbv_prob_cnn.ros.bag_replay`
and ``nbv integrate`` read: ``/camera/depth/image``, ``/camera/depth/camera_info`` and
``/camera/pose`` (remappable), as the serialized CDR bytes received (raw subscriptions, no
decoding). Messages DDS reports lost before they reached the node are counted per topic,
logged as they happen and listed in the shutdown summary. The log time of a message is its
reception time on the node's clock (the rosbag2 convention); the header stamps inside the
messages are kept as published.

Whether the camera's messages reach the recorder is on ``/diagnostics``: status ``<node>: inputs``
(:class:`~nbv_prob_cnn.ros.readiness.InputReadiness`, also logged once as ``ready: ...``) turns OK
when every publisher of the camera topics that the node knows of is matched and has delivered a
message; from then on every message they publish is recorded or counted as lost. Wait for it
before the part of a run that must be in the bag.

The bag is created when the node starts (an existing ``output`` is never overwritten: the node
exits with status 1) and closed cleanly on SIGINT/SIGTERM, so the bag is complete and indexed.

Run: ``nbv node bag_record --ros-args -p output:=/tmp/run1``
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, TransformStamped
from nbv_prob_cnn_msgs.msg import VoxelGrid
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from visualization_msgs.msg import MarkerArray

from nbv_prob_cnn.basics.grid import OCCUPIED
from nbv_prob_cnn.perception.bags import (
    MSG_CAMERA_INFO,
    MSG_IMAGE,
    MSG_TRANSFORM,
    TOPIC_CAMERA_INFO,
    TOPIC_IMAGE,
    TOPIC_POSE,
    BagError,
    typestore,
)
from nbv_prob_cnn.perception.messages import (
    MSG_MARKER_ARRAY,
    MSG_POINT_CLOUD,
    MSG_POSE_STAMPED,
    points_to_cloud_msg,
    stamp_ns,
)
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import msg_to_grid
from nbv_prob_cnn.ros.parameters import declare_config, param
from nbv_prob_cnn.ros.qos import GRID_QOS, RELIABILITY, lost_message_counter, subscription_qos
from nbv_prob_cnn.ros.readiness import InputReadiness
from nbv_prob_cnn.ros.runtime import run_node

NODE_NAME = "bag_record"
#: The recorded planning output (``planning:=true``): topic -> (rclpy class, rosbag2 type name).
PLANNING_TOPICS = {
    "/nbv/markers": (MarkerArray, MSG_MARKER_ARRAY),
    "/nbv/next_best_view": (PoseStamped, MSG_POSE_STAMPED),
}
#: The occupied cells of each grid, as a PointCloud2 of cell centres.
TOPIC_GRID_OCCUPIED = "/nbv/grid_occupied"
#: topic -> (rclpy class, rosbag2 type name)
TOPICS = {
    TOPIC_IMAGE: (Image, MSG_IMAGE),
    TOPIC_CAMERA_INFO: (CameraInfo, MSG_CAMERA_INFO),
    TOPIC_POSE: (TransformStamped, MSG_TRANSFORM),
}


@dataclass
class BagRecordConfig:
    """Parameters of ``bag_record``."""

    output: str = param("", "new rosbag2 directory to create (required; never overwritten)")
    queue_size: int = param(100, "depth of the subscriptions", min_value=1, max_value=10000)
    qos_reliability: str = param("reliable", "subscriptions: reliable or best_effort", choices=RELIABILITY)
    planning: bool = param(
        False, "also record nbv/markers, nbv/next_best_view and the grid's occupied cells as a PointCloud2 "
        "(/nbv/grid_occupied), so a run opens in any mcap viewer and in `nbv view`",
    )  # fmt: skip


class BagRecord(Node):
    """Writes every message of the camera topics to a new mcap bag."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = declare_config(self, BagRecordConfig)
        output = self.config.output
        qos = subscription_qos(self.config.queue_size, self.config.qos_reliability)
        if not output:
            raise ValueError("parameter 'output' is required (path of the new bag directory)")
        self.path = Path(output).expanduser()
        self.counts: Counter[str] = Counter()
        self.lost_in_transport: dict[str, int] = {}  # topic -> messages DDS reported lost before delivery
        self._writer: Any = self._open_writer()
        self._connections: dict[str, Any] = {}
        store = typestore()
        # recorded under its resolved name
        resolved = {default_topic: self.resolve_topic_name(names.relative(default_topic)) for default_topic in TOPICS}
        #: ``/diagnostics`` ``<node>: inputs``: OK once every camera publisher's messages arrive
        self.inputs = InputReadiness(self, list(resolved.values()))
        for default_topic, (msg_class, msgtype) in TOPICS.items():
            topic = resolved[default_topic]
            self._connections[topic] = self._writer.add_connection(topic, msgtype, typestore=store)
            self.create_subscription(
                msg_class, names.relative(default_topic), self._callback(topic, camera=True), qos, raw=True,
                event_callbacks=self.inputs.events(topic, lost_message_counter(self, self.lost_in_transport, topic)),
            )  # fmt: skip
        if self.config.planning:
            for topic, (msg_class, msgtype) in PLANNING_TOPICS.items():
                name = self.resolve_topic_name(names.relative(topic))
                self._connections[name] = self._writer.add_connection(name, msgtype, typestore=store)
                self.create_subscription(msg_class, names.relative(topic), self._callback(name), 10, raw=True)
            cloud = self.resolve_topic_name(names.relative(TOPIC_GRID_OCCUPIED))
            self._connections[cloud] = self._writer.add_connection(cloud, MSG_POINT_CLOUD, typestore=store)
            self.create_subscription(VoxelGrid, names.GRID, self._grid_callback(cloud), GRID_QOS)
        self.get_logger().info(f"recording {sorted(self._connections)} to {self.path}")

    def _grid_callback(self, topic: str):
        """Writes the occupied cells of each grid as a PointCloud2 of their centres."""
        connection, store = self._connections[topic], typestore()

        def write(msg: VoxelGrid) -> None:
            if self._writer is None:
                return
            try:
                state, geometry = msg_to_grid(msg)
            except ValueError as exc:
                self.get_logger().warning(f"grid not recorded: {exc}", throttle_duration_sec=5.0)
                return
            cells = np.argwhere(state == OCCUPIED)
            points = geometry.cell_centre(cells) if len(cells) else np.zeros((0, 3))
            if points.shape[1] == 2:  # a 2D grid: z = 0
                points = np.column_stack([points, np.zeros(len(points))])
            cloud = points_to_cloud_msg(points, stamp_ns(msg.header.stamp), msg.header.frame_id or "world")
            self._writer.write(
                connection, self.get_clock().now().nanoseconds, store.serialize_cdr(cloud, MSG_POINT_CLOUD)
            )
            self.counts[topic] += 1

        return write

    def _open_writer(self) -> Any:
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

        if self.path.exists():
            raise BagError(f"{self.path}: exists already; a bag is never overwritten")
        try:
            writer = Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
            writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"{self.path}: cannot create the bag ({exc})") from exc
        return writer

    def _callback(self, topic: str, camera: bool = False) -> Callable[[bytes], None]:
        connection = self._connections[topic]

        def write(raw: bytes) -> None:
            if self._writer is None:
                return
            self._writer.write(connection, self.get_clock().now().nanoseconds, raw)
            self.counts[topic] += 1
            if camera:
                self.inputs.received(topic)

        return write

    def close(self) -> None:
        """Finish the bag (mcap summary, metadata.yaml); idempotent."""
        if self._writer is not None:
            writer, self._writer = self._writer, None
            writer.close()

    def destroy_node(self) -> None:
        self.close()
        super().destroy_node()

    def summary(self) -> str:
        per_topic = ", ".join(f"{t} {n}" for t, n in sorted(self.counts.items())) or "nothing"
        lost = ", ".join(f"{t} {n}" for t, n in sorted(self.lost_in_transport.items()) if n) or "none"
        return (
            f"wrote {sum(self.counts.values())} message(s) to {self.path} ({per_topic}); "
            f"lost in transport before recording (reported by DDS): {lost}"
        )


def main(args: list[str] | None = None) -> int:
    """Record until interrupted (bag closed cleanly); 1 when the bag cannot be created."""
    return run_node(BagRecord, args, threads=1, summary=lambda node: node.summary())


if __name__ == "__main__":
    raise SystemExit(main())
