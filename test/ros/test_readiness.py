"""A recorder's input readiness (``<node>: inputs`` on ``/diagnostics``): OK only once every known
publisher is matched and has delivered a message since it matched; a newly matched publisher
makes the topic wait for its next message again."""

from __future__ import annotations

import os
import time

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("diagnostic_msgs")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402

from nbv_prob_cnn.ros.readiness import (  # noqa: E402
    NO_PUBLISHER,
    RECEIVING,
    InputReadiness,
    TopicInput,
    input_readiness,
    inputs_state,
)

OK, WARN = DiagnosticStatus.OK, DiagnosticStatus.WARN


def test_the_state_of_inputs_by_hand() -> None:
    assert inputs_state({"/a": TopicInput(), "/b": TopicInput()}) == (WARN, NO_PUBLISHER)
    # a publisher in the graph that the subscription has not matched (yet, or QoS that does not fit)
    assert inputs_state({"/a": TopicInput(publishers=2, matched=1, reached=True)}) == (
        WARN, "/a: 1 of 2 publisher(s) matched"
    )  # fmt: skip
    # matched on the subscriber's side only: no message yet
    assert inputs_state({"/a": TopicInput(publishers=1, matched=1)}) == (WARN, "/a: waiting for the first message")
    # both topics waiting: both named
    level, message = inputs_state({"/a": TopicInput(1, 1), "/b": TopicInput(1, 0)})
    assert level == WARN and message == "/a: waiting for the first message; /b: 0 of 1 publisher(s) matched"
    # every topic with a publisher reached; a topic without one (e.g. no /camera/pose on an arm) does not hold it up
    ready = {"/a": TopicInput(1, 1, 5, True), "/pose": TopicInput()}
    assert inputs_state(ready) == (OK, RECEIVING)


@pytest.fixture
def nodes(ros_domain):
    ros_domain(229 + os.getpid() % 3)  # 229..231: no other test uses these
    contexts, made = [], []
    for name in ("recorder", "camera"):
        context = rclpy.Context()
        rclpy.init(context=context)
        contexts.append(context)
        made.append(rclpy.create_node(name, context=context))
    executors = []
    for node, context in zip(made, contexts, strict=True):
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executors.append(executor)
    yield made, executors
    for executor, node, context in zip(executors, made, contexts, strict=True):
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_ready_only_after_a_message_from_every_matched_publisher(nodes) -> None:
    (recorder, camera), executors = nodes
    statuses: list[tuple[bytes, str]] = []

    def spin_until(predicate, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not predicate() and time.monotonic() < deadline:
            for executor in executors:
                executor.spin_once(timeout_sec=0.01)
        return predicate()

    topic = recorder.resolve_topic_name("numbers")
    inputs = InputReadiness(recorder, [topic])
    received = []

    def on_message(msg: Int32) -> None:
        received.append(msg.data)
        inputs.received(topic)

    recorder.create_subscription(Int32, "numbers", on_message, 10, event_callbacks=inputs.events(topic))
    camera.create_subscription(
        DiagnosticArray, "/diagnostics", lambda a: statuses.extend(input_readiness(a).values()), 50
    )  # fmt: skip

    def last() -> tuple[bytes, str] | None:
        return statuses[-1] if statuses else None

    assert spin_until(lambda: last() == (WARN, NO_PUBLISHER), 20.0), last()
    first = camera.create_publisher(Int32, "numbers", 10)
    # matched on both sides, but nothing sent: not ready
    assert spin_until(lambda: last() == (WARN, "/numbers: waiting for the first message"), 20.0), last()
    assert spin_until(lambda: first.get_subscription_count() == 1, 20.0)
    first.publish(Int32(data=1))
    assert spin_until(lambda: last() == (OK, RECEIVING), 20.0), last()
    assert received == [1]
    # a second publisher: the topic waits for a message again (the new one may not have matched us yet)
    second = camera.create_publisher(Int32, "numbers", 10)
    assert spin_until(lambda: last() is not None and last()[0] == WARN, 20.0), last()
    assert spin_until(lambda: second.get_subscription_count() == 1, 20.0)
    second.publish(Int32(data=2))
    assert spin_until(lambda: last() == (OK, RECEIVING), 20.0), last()
    assert received == [1, 2]
