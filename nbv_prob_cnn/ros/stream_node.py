"""A node's high-rate input streams (``joint_states``, ``/tf``) on a side node with its own thread.

rclpy's executors rebuild their wait set over every entity of a node (its services, clients,
timers, action servers) each time they wake. In a node like ``nbv_planner`` that costs about
1 ms of Python per message; a robot publishes ``joint_states`` and ``/tf`` at 100-1000 Hz, so
the planner would spend a good part of a core just receiving them, beside the CNN and the ray
casting it waits for (measured: 0.93 ms per ``JointState`` in a node with 8 services, 4 clients and a
timer under a ``MultiThreadedExecutor``, 0.19 ms on a side node with only the subscriptions under
a ``SingleThreadedExecutor``; ``docs/ros.md``). tf2_ros' ``TransformListener(spin_thread=True)``
does the same for the same reason.

:class:`StreamNode` is that side node: ``<owner>_streams`` in the owner's namespace and context
(so global remappings such as ``-r __ns:=/robot1`` and ``-r /tf:=tf`` apply to it as well), no
parameter services, spun by a ``SingleThreadedExecutor`` in a daemon thread. Its callbacks run in
that thread, concurrently with the owner's: what they touch must be locked (the joint-state
trackers and the TF buffer are).
"""

from __future__ import annotations

import threading

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

#: Name suffix of a node's side node (``nbv_planner`` → ``nbv_planner_streams``).
STREAMS_SUFFIX = "_streams"
#: How long the side node's executor waits at a time (s): bounds the stop latency.
SPIN_PERIOD_S = 0.1


class StreamNode:
    """The side node of ``owner`` for its high-rate subscriptions (see the module doc).

    Create subscriptions on :attr:`node`; call :meth:`destroy` before destroying the owner.
    """

    def __init__(self, owner: Node) -> None:
        self.node = Node(
            owner.get_name() + STREAMS_SUFFIX, namespace=owner.get_namespace(), context=owner.context,
            start_parameter_services=False,
        )  # fmt: skip
        self._executor = SingleThreadedExecutor(context=owner.context)
        self._executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=self.node.get_name(), daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            while not self._stop.is_set() and self.node.context.ok():
                self._executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        except (ExternalShutdownException, KeyboardInterrupt):
            pass
        except Exception as exc:  # keep the owner serving; its streams are gone, say why
            if self.node.context.ok() and not self._stop.is_set():
                self.node.get_logger().error(f"stream thread stopped: {type(exc).__name__}: {exc}")

    def destroy(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (at most ``timeout_s``) and destroy the side node."""
        self._stop.set()
        self._thread.join(timeout=timeout_s)
        self._executor.shutdown(timeout_sec=0.0)
        if not self._thread.is_alive():
            self.node.destroy_node()
