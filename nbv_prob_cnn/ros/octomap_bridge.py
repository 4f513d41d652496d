"""``octomap_bridge``: the integrator's grid as an OctoMap, for MoveIt and anything else that reads
``octomap_msgs`` (docs/robot.md, "With MoveIt 2" and "With octomap_server").

Subscribes ``/nbv/grid`` (or ``/nbv/grid/compressed`` with ``grid_transport:=compressed``) and
publishes each changed grid as ``octomap_msgs/Octomap`` on ``/octomap_bridge/octomap`` (binary
``OcTree``, the grid's resolution, frame and stamp; reliable, transient local, depth 1, as
``octomap_server`` latches its map), at most ``max_rate_hz`` times a second: a grid that arrives
sooner is sent at the next slot, a grid equal to the last one sent (the integrator's republishing,
a frame that changed no cell) is not sent again. Empty cells become free leaves, occupied cells
occupied leaves and, with ``unknown_as_occupied`` (the default: what the camera has not seen may
be an obstacle), unknown cells occupied leaves too; cells outside the grid stay unknown.

With ``planning_scene:=true`` the same grid also goes to ``/planning_scene`` as a
``moveit_msgs/PlanningScene`` diff whose ``world.octomap`` is the grid, placed by its ``origin``
(move_group's planning scene monitor applies it to the scene it collision-checks against).

A grid whose corner is off its cells' lattice is published on ``octomap`` moved onto it by less
than half a cell (logged once with the shift); the planning scene's octomap is exact. A grid that
cannot be an OcTree (2D, or beyond the tree's 65536 cells a side) is counted and logged, and the
node keeps serving.

Run: ``nbv node octomap_bridge --ros-args -p planning_scene:=true``
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
from nbv_prob_cnn_msgs.msg import VoxelGrid
from octomap_msgs.msg import Octomap
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.perception.octomap_codec import OctomapError
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import msg_to_grid
from nbv_prob_cnn.ros.grid_holder import LatestGrid, grid_transport_param
from nbv_prob_cnn.ros.octomap_messages import grid_to_octomap_msg, planning_scene_diff
from nbv_prob_cnn.ros.parameters import declare_config, param
from nbv_prob_cnn.ros.qos import GRID_QOS
from nbv_prob_cnn.ros.runtime import run_node

NODE_NAME = "octomap_bridge"
#: MoveIt's planning scene diffs: move_group subscribes reliable, volatile.
PLANNING_SCENE_QOS = QoSProfile(depth=10)


@dataclass
class OctomapBridgeConfig:
    """Parameters of ``octomap_bridge``."""

    grid_transport: str = grid_transport_param()
    unknown_as_occupied: bool = param(
        True, "unknown cells go in as occupied leaves (conservative: MoveIt then avoids what the camera has not "
        "seen); false: they stay out of the tree (unknown)",
    )  # fmt: skip
    max_rate_hz: float = param(1.0, "at most this many OctoMaps a second", min_value=0.01, max_value=100.0)
    planning_scene: bool = param(
        False, "also publish each grid as a moveit_msgs/PlanningScene diff (world.octomap) on planning_scene"
    )


def same_grid(a: VoxelGrid, b: VoxelGrid | None) -> bool:
    """Whether two grid messages hold the same cells in the same place (the stamp aside)."""
    if b is None:
        return False
    placed = (a.header.frame_id, a.origin, a.resolution, a.size_x, a.size_y, a.size_z)
    return placed == (b.header.frame_id, b.origin, b.resolution, b.size_x, b.size_y, b.size_z) and bytes(
        a.data
    ) == bytes(b.data)


class OctomapBridge(Node):
    """Publishes the latest changed grid as an OctoMap (and a planning scene diff), rate-limited."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = cfg = declare_config(self, OctomapBridgeConfig)
        self.counts = dict.fromkeys(("grids", "octomaps", "unchanged", "refused", "planning_scenes"), 0)
        self._lock = threading.Lock()
        self._latest: VoxelGrid | None = None
        self._sent: VoxelGrid | None = None
        self._warned_shift = False
        self._octomap_pub = self.create_publisher(Octomap, names.OCTOMAP_BRIDGE_OCTOMAP, GRID_QOS)
        self._scene_pub = None
        if cfg.planning_scene:
            from moveit_msgs.msg import PlanningScene

            self._scene_pub = self.create_publisher(PlanningScene, names.PLANNING_SCENE, PLANNING_SCENE_QOS)
        self._grids = LatestGrid(self, on_grid=self._on_grid, transport=cfg.grid_transport)
        self.create_timer(1.0 / cfg.max_rate_hz, self._on_timer, callback_group=MutuallyExclusiveCallbackGroup())
        self.get_logger().info(
            f"{self._grids.topic} -> {self._octomap_pub.topic_name}"
            + (f" and {self._scene_pub.topic_name}" if self._scene_pub else "")
            + f", at most {cfg.max_rate_hz:g} Hz, unknown_as_occupied={cfg.unknown_as_occupied}"
        )

    def _on_grid(self, msg: VoxelGrid) -> None:
        with self._lock:
            self._latest = msg
            self.counts["grids"] += 1

    def _on_timer(self) -> None:
        with self._lock:
            msg = self._latest
        if msg is None or msg is self._sent:
            return
        if same_grid(msg, self._sent):
            self._sent = msg
            self.counts["unchanged"] += 1
            return
        self._sent = msg
        try:
            self._publish(msg)
        except (OctomapError, ValueError) as exc:
            self.counts["refused"] += 1
            self.get_logger().error(f"grid stamped {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d} not sent "
                                    f"({self.counts['refused']} so far): {exc}")  # fmt: skip

    def _publish(self, msg: VoxelGrid) -> None:
        start = time.perf_counter()
        state, geometry = msg_to_grid(msg)
        # VoxelGrid's resolution is a float32: the float64 OctoMap gets its shortest decimal (0.05, not 0.0500000007)
        geometry = GridGeometry(geometry.origin, float(str(np.float32(geometry.resolution))), geometry.shape)
        frame, stamp, unknown = msg.header.frame_id, msg.header.stamp, self.config.unknown_as_occupied
        octomap, shift = grid_to_octomap_msg(state, geometry, frame, stamp, unknown)
        if np.any(shift) and not self._warned_shift:
            self._warned_shift = True
            self.get_logger().warning(
                f"the grid's corner {list(geometry.origin)} is not a whole number of {geometry.resolution:g} m cells "
                f"from {frame!r}'s origin: the octomap's cells are moved by {(shift * 1000).round(2).tolist()} mm "
                "onto the OcTree's lattice (set the integrator's origin to multiples of voxel_size to avoid it; "
                "the planning scene's octomap is exact)"
            )
        self._octomap_pub.publish(octomap)
        self.counts["octomaps"] += 1
        if self._scene_pub is not None:
            reuse = octomap if not np.any(shift) else None
            self._scene_pub.publish(planning_scene_diff(state, geometry, frame, stamp, unknown, reuse))
            self.counts["planning_scenes"] += 1
        self.get_logger().info(
            f"octomap of {len(octomap.data)} bytes from grid {list(state.shape)} "
            f"in {time.perf_counter() - start:.2f} s",
            throttle_duration_sec=10.0,
        )

    def summary(self) -> str:
        return ", ".join(f"{name} {value}" for name, value in self.counts.items())


def main(args: list[str] | None = None) -> int:
    """Run the node until interrupted; 1 on a configuration error."""
    return run_node(OctomapBridge, args, threads=2, summary=lambda node: node.summary())


if __name__ == "__main__":
    raise SystemExit(main())
