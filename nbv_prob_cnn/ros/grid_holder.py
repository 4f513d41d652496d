"""The newest occupancy grid of ``/nbv/grid`` that a node plans on: one subscription (latched
QoS, so a node started late still gets the last grid) to the raw topic or to its compressed twin
``/nbv/grid/compressed``, the newest message, and a wait for a grid that includes a given frame."""

from __future__ import annotations

import threading
from collections.abc import Callable

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
    """

    def __init__(
        self,
        node: Node,
        *,
        callback_group=None,
        on_grid: Callable[[VoxelGrid], None] | None = None,
        transport: str = "raw",
    ) -> None:
        if transport not in GRID_TRANSPORTS:
            raise ValueError(f"grid_transport: {transport!r} is not one of {list(GRID_TRANSPORTS)}")
        self._condition = threading.Condition()
        self._grid: VoxelGrid | None = None
        self._on_grid = on_grid
        self._logger = node.get_logger()
        self.refused = 0  # compressed grids that could not be inflated
        self.topic = names.GRID if transport == "raw" else names.GRID_COMPRESSED
        if transport == "raw":
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
                raise ValueError(f"no grid received yet on /{self.topic}")
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
