"""The newest occupancy grid that a node plans on: one subscription (latched QoS, so a node started
late still gets the last grid) to the integrator's ``/nbv/grid``, its compressed twin
``/nbv/grid/compressed``, or (``grid_source:=octomap``) an ``octomap_msgs/Octomap`` topic such as
``octomap_server``'s ``/octomap_binary``; the newest grid, and a wait for a grid that includes a
given frame.

From an OctoMap the grid is the tree's cells inside ``octomap_box_min`` .. ``octomap_box_max``
(metres in the OctoMap's frame, corners on its lattice; :mod:`~nbv_prob_cnn.perception.octomap_codec`):
free leaves empty, occupied leaves (occupancy at or above ``octomap_occupancy_threshold``)
occupied, the rest unknown. It stays in the OctoMap's frame, or with ``octomap_grid_frame`` is
moved into that frame by TF (a translation). A message that cannot be read (another tree class, a
truncated or corrupt stream, a box off the tree's lattice, a frame TF cannot reach or a rotated
one) is refused: logged with the reason, counted, and the last good grid kept."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from nbv_prob_cnn_msgs.msg import CompressedVoxelGrid, VoxelGrid
from rclpy.node import Node

from nbv_prob_cnn.basics.interrupt import Interrupt, wait_on
from nbv_prob_cnn.perception.messages import stamp_ns
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import decompress_grid_msg
from nbv_prob_cnn.ros.parameters import param
from nbv_prob_cnn.ros.qos import GRID_QOS

#: Values of the ``grid_transport`` parameter: the topic a node reads its grids from.
GRID_TRANSPORTS = ("raw", "compressed")
#: Values of the ``grid_source`` parameter.
GRID_SOURCES = ("integrator", "octomap")


def _check_corner(value) -> None:
    if len(value) != 3 or not all(isinstance(v, int | float) and np.isfinite(v) for v in value):
        raise ValueError(f"expected 3 finite numbers [m], got {value!r}")


@dataclass
class GridSourceParams:
    """Where a planning node's grids come from: the integrator, or an OctoMap topic in a box."""

    grid_source: str = param(
        "integrator", "grids from the integrator (nbv/grid, by grid_transport) or an octomap_msgs/Octomap topic "
        "(octomap_topic)", choices=GRID_SOURCES,
    )  # fmt: skip
    octomap_topic: str = param(names.OCTOMAP_BINARY, "grid_source octomap: the topic (octomap_server's binary map)")
    octomap_box_min: list = param(
        [-0.75, -0.75, 0.0], "grid_source octomap: the grid's min corner, metres in the OctoMap's frame, on its "
        "lattice (whole cells from the frame's origin)", check=_check_corner,
    )  # fmt: skip
    octomap_box_max: list = param(
        [0.75, 0.75, 1.1], "grid_source octomap: the grid's max corner (as octomap_box_min)", check=_check_corner
    )
    octomap_occupancy_threshold: float = param(
        0.5, "grid_source octomap: a leaf at or above this occupancy is occupied (OctoMap's default)",
        min_value=0.001, max_value=0.999,
    )  # fmt: skip
    octomap_grid_frame: str = param(
        "", "grid_source octomap: the grids' frame ('' = the OctoMap's; another is reached by TF, a translation)"
    )


def grid_transport_param() -> str:
    """``grid_transport``: the grid topic a node reads, ``raw`` by default."""
    return param(
        "raw", "grids from nbv/grid (raw) or nbv/grid/compressed (zlib: room-sized grids)", choices=GRID_TRANSPORTS
    )


class LatestGrid:
    """The newest ``/nbv/grid`` message ``node`` received.

    Args:
        node: subscribes to the grid topic (``names.GRID``, :data:`~nbv_prob_cnn.ros.qos.GRID_QOS`).
        callback_group: of the subscription.
        on_grid: called with each message once it is stored (in the subscription's callback).
        transport: ``raw`` (``names.GRID``) or ``compressed`` (``names.GRID_COMPRESSED``: each
            message is inflated to the :class:`VoxelGrid` it carries; one that cannot be is logged
            on ``node``'s logger, counted in :attr:`refused` and not stored).
        source: the node's config; with ``grid_source`` ``octomap`` the grids come from its
            ``octomap_topic`` instead (the module docstring), ``transport`` aside.
    """

    def __init__(
        self,
        node: Node,
        *,
        callback_group=None,
        on_grid: Callable[[VoxelGrid], None] | None = None,
        transport: str = "raw",
        source: GridSourceParams | None = None,
    ) -> None:
        if transport not in GRID_TRANSPORTS:
            raise ValueError(f"grid_transport: {transport!r} is not one of {list(GRID_TRANSPORTS)}")
        self._condition = threading.Condition()
        self._grid: VoxelGrid | None = None
        self._on_grid = on_grid
        self._logger = node.get_logger()
        self.refused = 0  # compressed grids that could not be inflated, OctoMaps that could not be read
        self.topic = names.GRID if transport == "raw" else names.GRID_COMPRESSED
        grid_source = source.grid_source if source is not None else "integrator"
        self._octomap = source if grid_source == "octomap" else None
        self._tf = None
        if grid_source == "octomap":
            from octomap_msgs.msg import Octomap

            assert source is not None
            cfg = source
            self.topic = cfg.octomap_topic
            if cfg.octomap_grid_frame:
                from nbv_prob_cnn.ros.tf_listener import TfListener

                self._tf = TfListener(node)
            node.create_subscription(
                Octomap, cfg.octomap_topic, self._receive_octomap, GRID_QOS, callback_group=callback_group
            )
        elif transport == "raw":
            node.create_subscription(VoxelGrid, names.GRID, self.receive, GRID_QOS, callback_group=callback_group)
        else:
            node.create_subscription(
                CompressedVoxelGrid, names.GRID_COMPRESSED, self._receive_compressed, GRID_QOS,
                callback_group=callback_group,
            )  # fmt: skip

    def _receive_compressed(self, msg: CompressedVoxelGrid) -> None:
        try:
            grid = decompress_grid_msg(msg)
        except ValueError as exc:
            self.refused += 1
            self._logger.error(f"{names.GRID_COMPRESSED}: grid refused ({self.refused} so far): {exc}")
            return
        self.receive(grid)

    def _receive_octomap(self, msg) -> None:
        try:
            grid = self._octomap_grid(msg)
        except (ValueError, LookupError) as exc:  # OctomapError, TransformError
            self.refused += 1
            self._logger.error(f"{self.topic}: OctoMap refused ({self.refused} so far): {exc}")
            return
        self.receive(grid)

    def _octomap_grid(self, msg) -> VoxelGrid:
        """The grid of an OctoMap message in the box, in ``octomap_grid_frame`` when one is set."""
        from nbv_prob_cnn.ros.octomap_messages import octomap_to_grid_msg

        cfg = self._octomap
        assert cfg is not None
        grid = octomap_to_grid_msg(msg, cfg.octomap_box_min, cfg.octomap_box_max, cfg.octomap_occupancy_threshold)
        target, frame = cfg.octomap_grid_frame.lstrip("/"), msg.header.frame_id.lstrip("/")
        if self._tf is None or target == frame:
            return grid
        try:
            matrix, _ = self._tf.lookup(target, frame)
        except LookupError as exc:
            raise LookupError(
                f"the OctoMap's frame {frame!r} cannot be reached by TF from octomap_grid_frame {target!r}: {exc}"
            ) from None
        if not np.allclose(matrix[:3, :3], np.eye(3), atol=1e-6):
            raise ValueError(
                f"the OctoMap's frame {frame!r} is rotated against octomap_grid_frame {target!r}; a grid is axis-"
                f"aligned: leave octomap_grid_frame empty to plan in {frame!r}"
            )
        position = grid.origin.position
        position.x, position.y, position.z = (
            float(v) for v in np.array([position.x, position.y, position.z]) + matrix[:3, 3]
        )
        grid.header.frame_id = target
        return grid

    def receive(self, msg: VoxelGrid) -> None:
        """Store ``msg`` as the newest grid and wake the waits (the subscription's callback)."""
        with self._condition:
            self._grid = msg
            self._condition.notify_all()
        if self._on_grid is not None:
            self._on_grid(msg)

    def latest(self) -> VoxelGrid:
        """The newest grid.

        Raises:
            ValueError: no grid has arrived yet.
        """
        with self._condition:
            if self._grid is None:
                raise ValueError(f"no grid received yet on /{self.topic.lstrip('/')}")
            return self._grid

    def wait_for_stamp(self, min_stamp_ns: int, timeout_s: float, interrupt: Interrupt | None = None) -> VoxelGrid:
        """Wait for a grid stamped at or after ``min_stamp_ns`` (one that includes the frame taken
        then) and return it.

        Raises:
            TimeoutError: none within ``timeout_s``.
            WaitInterruptedError: ``interrupt`` was triggered first.
        """

        def arrived() -> bool:
            return self._grid is not None and stamp_ns(self._grid.header.stamp) >= min_stamp_ns

        with self._condition:
            if not wait_on(self._condition, arrived, timeout_s, interrupt) or self._grid is None:
                raise TimeoutError(f"no grid including the frame at {min_stamp_ns} ns within {timeout_s:.0f} s")
            return self._grid
