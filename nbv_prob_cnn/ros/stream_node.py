"""A node's high-rate input streams (``joint_states``, ``/tf``) on a side node with its own thread.

rclpy's executors rebuild their wait set over every entity of a node (its services, clients,
timers, action servers) each time they wake. In a node like ``nbv_planner`` that costs about
1 ms of Python per message; a robot publishes ``joint_states`` and ``/tf`` at 100-1000 Hz, so
the planner would spend a good part of a core just receiving them, beside the CNN and the ray
casting it waits for (``nbv bench --suite ros_streams``; ``docs/ros.md``). tf2_ros'
``TransformListener(spin_thread=True)`` moves its subscriptions to a thread of their own for the
same reason.

Even a side node's executor costs about 0.6 ms of Python per message (it rebuilds its wait set,
wraps the callback in a task and switches threads at every wake): with four listeners of a 50 Hz
arm (``joint_states`` of the arm and of the gripper, ``/tf``) that was a core of the two this
project is tested on. :class:`StreamNode` therefore runs no executor: its thread wakes every
:data:`DRAIN_PERIOD_S` and takes every waiting message of every subscription of the side node
(rcl's take, in a loop), calling each callback in arrival order per subscription. What it costs
is then the messages' deserialisation and the callbacks, plus 100 cheap wakes a second. A
subscription's queue (its QoS depth) must hold what arrives in one period: 10 messages is
1000 Hz. Callbacks of the side node run in its thread, concurrently with the owner's: what they
touch must be locked (the joint-state trackers and the TF buffer are). An exception in a callback
is logged (at most every 5 s per subscription) and counted in :attr:`StreamNode.callback_errors`;
the other messages and subscriptions go on. Only subscriptions belong on the side node (no
timers, services, clients or subscription event callbacks: nothing would run them).

:class:`StreamNode` is that side node: ``<owner>_streams`` in the owner's namespace and context
(so global remappings such as ``-r __ns:=/robot1`` and ``-r /tf:=tf`` apply to it as well), no
parameter services, drained by a daemon thread.
"""

from __future__ import annotations

import threading
from collections import Counter

from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.subscription import Subscription

#: Name suffix of a node's side node (``nbv_planner`` → ``nbv_planner_streams``).
STREAMS_SUFFIX = "_streams"
#: Seconds between two drains of the side node's subscriptions (the added latency, at most).
DRAIN_PERIOD_S = 0.01


class StreamNode:
    """The side node of ``owner`` for its high-rate subscriptions (see the module doc).

    Create subscriptions on :attr:`node`; call :meth:`destroy` before destroying the owner.
    """

    def __init__(self, owner: Node) -> None:
        self.node = Node(
            owner.get_name() + STREAMS_SUFFIX, namespace=owner.get_namespace(), context=owner.context,
            start_parameter_services=False,
        )  # fmt: skip
        #: topic -> exceptions raised by its callback (each logged, at most every 5 s)
        self.callback_errors: Counter[str] = Counter()
        self._drain_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=self.node.get_name(), daemon=True)
        self._thread.start()

    def drain(self) -> int:
        """Take and handle every message waiting now on the side node's subscriptions (the
        thread does this every :data:`DRAIN_PERIOD_S`; a caller may too, e.g. before a lookup
        that wants the newest sample); the number of messages handled."""
        handled = 0
        with self._drain_lock:
            for subscription in list(self.node.subscriptions):
                handled += self._drain_one(subscription)
        return handled

    def _drain_one(self, subscription: Subscription) -> int:
        with_info = subscription._callback_type is Subscription.CallbackType.WithMessageInfo
        handled = 0
        while not self._stop.is_set():
            try:
                with subscription.handle:
                    taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
            except InvalidHandle:  # destroyed meanwhile
                return handled
            if taken is None:
                return handled
            handled += 1
            try:
                subscription.callback(*taken) if with_info else subscription.callback(taken[0])
            except Exception as exc:  # keep the stream flowing; say what failed
                topic = subscription.topic_name
                self.callback_errors[topic] += 1
                self.node.get_logger().error(
                    f"{topic}: callback failed ({type(exc).__name__}: {exc}); "
                    f"{self.callback_errors[topic]} failure(s) so far",
                    throttle_duration_sec=5.0,
                )
        return handled

    def _run(self) -> None:
        while not self._stop.wait(DRAIN_PERIOD_S):
            if not self.node.context.ok():
                return
            self.drain()

    def destroy(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (at most ``timeout_s``) and destroy the side node."""
        self._stop.set()
        self._thread.join(timeout=timeout_s)
        if not self._thread.is_alive():
            self.node.destroy_node()
