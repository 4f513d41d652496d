"""Whether a node is ready, on ``/diagnostics``: the planner's set-up and the inputs of a recorder.

Each state is one ``diagnostic_msgs/DiagnosticStatus`` named ``<node>: <what>``, published once a
second and on every change (:class:`StatusPublisher`).

**The planner** (``<node>: planning``, :class:`ReadinessPublisher`). With ``use_arm`` the planner
loads or builds the capability map and the collision model of a grid when the grid's first
message arrives (tens of seconds on a machine without the cached map):

* ``OK``, ``"ready"``: a plan starts at once;
* ``WARN``: ``"waiting for the first grid"`` or ``"arm set-up for the grid running"`` (a plan
  asked for now waits for it);
* ``ERROR``: the arm set-up failed (the message says why; plans report it too).

Clients that time an exploration (``explore_client``, the benchmarks) wait for ``OK`` before
they send the goal, so the set-up is not counted as the first view's planning time.

**A recorder's inputs** (``<node>: inputs``, :class:`InputReadiness`; ``bag_record`` and
``integrator``). ``OK`` means: every message the publishers of its input topics publish from now
on is received (recorded, integrated or dropped under a counted reason) or counted as lost in
transport. A subscription's own *matched* event is not enough for that: it says that the
subscriber's side has matched a publisher, while the publisher's side may match the subscriber
later (each side learns of the other on its own, seconds apart on a loaded machine), and a
volatile publisher does not send what it published before it matched. So a topic counts as
reached only when a message has arrived since its last newly matched publisher:

* ``OK``, ``"receiving from every publisher"``: on every input topic each publisher the node
  knows of (graph) is matched, and each topic with a publisher has delivered a message since;
* ``WARN``: ``"no publisher yet"`` (nothing to record), or what it waits for per topic:
  ``"<topic>: 1 of 2 publisher(s) matched"``, ``"<topic>: waiting for the first message"``.

The status carries one value per topic (``<topic>``: ``"<matched> matched, <n> received"``).
The node logs the first time it becomes ready. Test scripts and recorders' users wait for ``OK``
before they send what must be recorded (:func:`input_readiness`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.event_handler import SubscriptionEventCallbacks

from nbv_prob_cnn.ros import names

TOPIC_DIAGNOSTICS = names.DIAGNOSTICS
#: Suffix of the planner's status name (``<fully qualified node name>: planning``).
STATUS_SUFFIX = ": planning"
#: Suffix of a recorder's input status name (``<fully qualified node name>: inputs``).
INPUTS_SUFFIX = ": inputs"
#: Seconds between two publications of an unchanged state.
PERIOD_S = 1.0

READY = "ready"
WAITING_FOR_GRID = "waiting for the first grid"
SETTING_UP = "arm set-up for the grid running"
RECEIVING = "receiving from every publisher"
NO_PUBLISHER = "no publisher yet"


class StatusPublisher:
    """One status ``<node><suffix>`` on ``/diagnostics`` (``publisher``), every :data:`PERIOD_S` and
    on every change."""

    def __init__(self, node, publisher, suffix: str, level: bytes, message: str, callback_group=None) -> None:
        self._node = node
        self._lock = threading.Lock()
        self._level, self._message = level, message
        self._values: list[KeyValue] = []
        self.name = node.get_fully_qualified_name() + suffix
        self._pub = publisher
        node.create_timer(PERIOD_S, self.publish, callback_group=callback_group)

    def set(self, level: bytes, message: str, values: dict[str, str] | None = None) -> None:
        """Change the state; publish it now when the level or the message changed (new ``values``
        alone go out with the next periodic publication)."""
        with self._lock:
            changed = (level, message) != (self._level, self._message)
            self._level, self._message = level, message
            if values is not None:
                self._values = [KeyValue(key=k, value=v) for k, v in values.items()]
        if changed:
            self.publish()

    def publish(self) -> None:
        if not self._node.context.ok():
            return
        with self._lock:
            status = DiagnosticStatus(level=self._level, name=self.name, message=self._message, values=self._values)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(array)


class ReadinessPublisher:
    """Publishes the planner's readiness on ``/diagnostics`` (see the module doc)."""

    def __init__(self, node, ready: bool, callback_group=None) -> None:
        publisher = node.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._status = StatusPublisher(
            node, publisher, STATUS_SUFFIX, DiagnosticStatus.OK if ready else DiagnosticStatus.WARN,
            READY if ready else WAITING_FOR_GRID, callback_group,
        )  # fmt: skip

    def set(self, level: bytes, message: str) -> None:
        """Change the state; publish it now when it changed."""
        self._status.set(level, message)

    def publish(self) -> None:
        self._status.publish()


@dataclass
class TopicInput:
    """What a node knows of one input topic."""

    publishers: int = 0  #: publishers in the graph (this node's view)
    matched: int = 0  #: publishers its subscription has matched
    received: int = 0  #: messages received
    reached: bool = False  #: a message arrived since the last newly matched publisher


def inputs_state(topics: dict[str, TopicInput]) -> tuple[bytes, str]:
    """``(level, message)`` of a node's inputs (the rule of the module doc)."""
    waiting = []
    for topic, t in topics.items():
        if t.matched < t.publishers:
            waiting.append(f"{topic}: {t.matched} of {t.publishers} publisher(s) matched")
        elif t.matched and not t.reached:
            waiting.append(f"{topic}: waiting for the first message")
    if waiting:
        return DiagnosticStatus.WARN, "; ".join(waiting)
    if not any(t.matched for t in topics.values()):
        return DiagnosticStatus.WARN, NO_PUBLISHER
    return DiagnosticStatus.OK, RECEIVING


class InputReadiness:
    """A recorder's input readiness on ``/diagnostics`` (``<node>: inputs``, see the module doc).

    ``topics`` are resolved names (``node.resolve_topic_name``). Give each input subscription
    :meth:`events` of its topic (its matched event) and call :meth:`received` from its callback.
    """

    def __init__(self, node, topics: Sequence[str], callback_group=None) -> None:
        self._node = node
        self._lock = threading.Lock()
        self._topics = {topic: TopicInput() for topic in topics}
        self._was_ready = False
        publisher = node.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._status = StatusPublisher(
            node, publisher, INPUTS_SUFFIX, DiagnosticStatus.WARN, NO_PUBLISHER, callback_group
        )
        # the graph's publisher counts change without an event here: looked at once a period
        node.create_timer(PERIOD_S, self.update, callback_group=callback_group)

    def events(self, topic: str, events: SubscriptionEventCallbacks | None = None) -> SubscriptionEventCallbacks:
        """``events`` (new ones when None) with a matched callback that tracks ``topic``."""
        events = events or SubscriptionEventCallbacks()
        entry = self._topics[topic]

        def on_matched(status) -> None:
            with self._lock:
                if status.current_count_change > 0:
                    entry.reached = False  # the new publisher may not have matched this subscription yet
                entry.matched = int(status.current_count)
            self.update()

        events.matched = on_matched
        return events

    def received(self, topic: str) -> None:
        """A message of ``topic`` arrived (cheap: publishes only when that changes the state)."""
        entry = self._topics[topic]
        entry.received += 1
        if not entry.reached:
            with self._lock:
                entry.reached = True
            self.update()

    def snapshot(self) -> dict[str, dict[str, int]]:
        """Per topic: ``publishers`` (graph), ``matched`` (by the subscription) and ``received``."""
        with self._lock:
            return {
                topic: {"publishers": e.publishers, "matched": e.matched, "received": e.received}
                for topic, e in self._topics.items()
            }

    def update(self) -> None:
        """Refresh the graph's publisher counts and publish the state."""
        if not self._node.context.ok():
            return
        counts = {topic: self._node.count_publishers(topic) for topic in self._topics}
        with self._lock:
            for topic, count in counts.items():
                self._topics[topic].publishers = count
            level, message = inputs_state(self._topics)
            values = {t: f"{e.matched} matched, {e.received} received" for t, e in self._topics.items()}
            first_ready = level == DiagnosticStatus.OK and not self._was_ready
            self._was_ready = self._was_ready or first_ready
        if first_ready:
            self._node.get_logger().info(f"ready: {message} on {', '.join(self._topics)}")
        self._status.set(level, message, values)


def planner_readiness(array: DiagnosticArray) -> tuple[bytes, str] | None:
    """``(level, message)`` of the first planner status in ``array``, None if it holds none
    (``level`` as ``DiagnosticStatus.level``: ``OK``, ``WARN``, ``ERROR``)."""
    return _status_with_suffix(array, STATUS_SUFFIX)


def input_readiness(array: DiagnosticArray) -> dict[str, tuple[bytes, str]]:
    """``{node name: (level, message)}`` of the input statuses in ``array`` (``/bag_record``: ...)."""
    return {
        status.name[: -len(INPUTS_SUFFIX)]: (status.level, status.message)
        for status in array.status
        if status.name.endswith(INPUTS_SUFFIX)
    }


def _status_with_suffix(array: DiagnosticArray, suffix: str) -> tuple[bytes, str] | None:
    for status in array.status:
        if status.name.endswith(suffix):
            return status.level, status.message
    return None


__all__ = [
    "InputReadiness", "ReadinessPublisher", "StatusPublisher", "TopicInput", "input_readiness", "inputs_state",
    "planner_readiness", "TOPIC_DIAGNOSTICS", "STATUS_SUFFIX", "INPUTS_SUFFIX",
]  # fmt: skip
