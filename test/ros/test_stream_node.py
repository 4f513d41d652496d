"""``StreamNode`` drains its subscriptions without an executor: every message arrives once and in
order, a burst larger than one drain is kept by the queue, callbacks with message info get it,
and a callback that raises is counted while the stream goes on."""

from __future__ import annotations

import os
import time

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("std_msgs")

from rclpy.node import Node  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402

from nbv_prob_cnn.ros.stream_node import STREAMS_SUFFIX, StreamNode  # noqa: E402


def wait_for(condition, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


@pytest.fixture
def owner(ros_domain):
    ros_domain(226 + os.getpid() % 3)  # 226..228: no other test uses these
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("stream_owner", context=context)
    yield node
    node.destroy_node()
    rclpy.shutdown(context=context)


def test_every_message_once_in_order_and_a_failing_callback_is_counted(owner) -> None:
    streams = StreamNode(owner)
    try:
        assert streams.node.get_name() == "stream_owner" + STREAMS_SUFFIX
        plain, with_info = [], []

        def on_plain(msg: Int32) -> None:
            if msg.data == 3:
                raise RuntimeError("message 3 is refused")
            plain.append(msg.data)

        streams.node.create_subscription(Int32, "numbers", on_plain, 100)
        streams.node.create_subscription(
            Int32, "numbers", lambda msg, info: with_info.append((msg.data, info)), 100
        )  # fmt: skip
        publisher = owner.create_publisher(Int32, "numbers", 100)
        assert wait_for(lambda: publisher.get_subscription_count() == 2, 10.0), "subscriptions did not match"
        for value in range(1, 51):  # a burst far larger than one 10 ms drain
            publisher.publish(Int32(data=value))
        assert wait_for(lambda: len(with_info) == 50, 10.0), len(with_info)
        assert wait_for(lambda: len(plain) == 49, 2.0), plain
        assert plain == [v for v in range(1, 51) if v != 3]  # once each, in order, past the failure
        assert [v for v, _ in with_info] == list(range(1, 51))
        assert all(info["source_timestamp"] > 0 for _, info in with_info)  # rmw message info is passed
        assert streams.callback_errors == {"/numbers": 1}
        assert streams.drain() == 0  # nothing waits any more
    finally:
        streams.destroy()
