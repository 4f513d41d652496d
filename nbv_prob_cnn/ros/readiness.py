"""Whether ``nbv_planner`` can plan without a set-up wait, on ``/diagnostics``.

With ``use_arm`` the planner loads or builds the capability map and the collision model of a
grid when the grid's first message arrives (tens of seconds on a machine without the cached map).
It reports that state as one ``diagnostic_msgs/DiagnosticStatus`` named ``<node>: planning``,
once a second and on every change:

* ``OK``, ``"ready"``: a plan starts at once;
* ``WARN``: ``"waiting for the first grid"`` or ``"arm set-up for the grid running"`` (a plan
  asked for now waits for it);
* ``ERROR``: the arm set-up failed (the message says why; plans report it too).

Clients that time an exploration (``explore_client``, the benchmarks) wait for ``OK`` before
they send the goal, so the set-up is not counted as the first view's planning time.
"""

from __future__ import annotations

import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from nbv_prob_cnn.ros import names

TOPIC_DIAGNOSTICS = names.DIAGNOSTICS
#: Suffix of the planner's status name (``<fully qualified node name>: planning``).
STATUS_SUFFIX = ": planning"
#: Seconds between two publications of an unchanged state.
PERIOD_S = 1.0

READY = "ready"
WAITING_FOR_GRID = "waiting for the first grid"
SETTING_UP = "arm set-up for the grid running"


class ReadinessPublisher:
    """Publishes the planner's readiness on ``/diagnostics`` (see the module doc)."""

    def __init__(self, node, ready: bool, callback_group=None) -> None:
        self._node = node
        self._lock = threading.Lock()
        self._level = DiagnosticStatus.OK if ready else DiagnosticStatus.WARN
        self._message = READY if ready else WAITING_FOR_GRID
        self._name = node.get_fully_qualified_name() + STATUS_SUFFIX
        self._pub = node.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        node.create_timer(PERIOD_S, self.publish, callback_group=callback_group)

    def set(self, level: int, message: str) -> None:
        """Change the state and publish it now."""
        with self._lock:
            self._level, self._message = level, message
        self.publish()

    def publish(self) -> None:
        with self._lock:
            status = DiagnosticStatus(level=self._level, name=self._name, message=self._message)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(array)


def planner_readiness(array: DiagnosticArray) -> tuple[bytes, str] | None:
    """``(level, message)`` of the first planner status in ``array``, None if it holds none
    (``level`` as ``DiagnosticStatus.level``: ``OK``, ``WARN``, ``ERROR``)."""
    for status in array.status:
        if status.name.endswith(STATUS_SUFFIX):
            return status.level, status.message
    return None


__all__ = ["ReadinessPublisher", "planner_readiness", "TOPIC_DIAGNOSTICS", "STATUS_SUFFIX"]
