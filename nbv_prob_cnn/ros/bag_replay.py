"""``bag_replay``: publish the messages of a rosbag2 on their original topics, paced by bag time.

There is no ``ros2 bag play`` here; this node stands in for it (docs/method.md#node-graph: ``bag_replay`` feeds the
integrator the camera topics of a recorded bag). Messages are published as the serialized CDR
bytes stored in the bag (no decoding), with the publish times following the bag's log times
divided by ``rate``.

The whole bag is validated before anything is published (every message read and, for standard
types, deserialized; counts checked against the bag's index: see
:func:`nbv_prob_cnn.perception.bags.read_raw_messages`). A missing, corrupt or truncated bag is
logged as an error and the node exits with status 1 having published nothing.

When the bag is done (``loop:=false``) the node waits until reliable subscribers acknowledged
everything (at most ``ack_timeout_s``), logs a summary and exits with status 0; with
``exit_when_done:=false`` it keeps running (publishers alive) until interrupted.

QoS: reliable, volatile, depth ``queue_size``. Messages published before a subscriber is
matched are lost (volatile), so ``wait_for_subscribers:=N`` holds the start until every topic
has N subscribers (at most ``wait_timeout_s``; the replay starts anyway after it, with a warning).

Run: ``nbv node bag_replay --ros-args -p bag:=bags/3dt_seed1000_sample -p rate:=2.0``
"""

from __future__ import annotations

import importlib
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from nbv_prob_cnn.perception.bags import BagError, bag_topics, read_raw_messages
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.common import declare_config, param, run_node

NODE_NAME = "bag_replay"


def message_class(msgtype: str) -> type:
    """The rclpy message class of ``pkg/msg/Name``.

    Raises:
        ValueError: not a message type name, or its package is not installed.
    """
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise ValueError(f"{msgtype!r} is not a message type name (pkg/msg/Name)")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"message type {msgtype} is not installed ({exc})") from exc


@dataclass
class BagReplayConfig:
    """Parameters of ``bag_replay``."""

    bag: str = param("", "rosbag2 directory or .mcap file (required)")
    rate: float = param(1.0, "replay speed factor (2.0 = twice as fast as recorded)", min_value=1e-3, max_value=1e4)
    loop: bool = param(False, "start again at the end, until interrupted")
    start_delay_s: float = param(
        0.0, "wait this long before the first message [s]", min_value=0.0, max_value=3600.0, attribute="start_delay"
    )
    exit_when_done: bool = param(True, "exit (status 0) after the last message; false: keep running")
    topics: str = param("", "comma-separated topics to replay; empty = every topic of the bag")
    queue_size: int = param(10, "publisher history depth", min_value=1, max_value=10000)
    wait_for_subscribers: int = param(
        0, "before starting, wait until every topic has this many subscribers", min_value=0, max_value=1000
    )
    wait_timeout_s: float = param(
        10.0, "longest wait for subscribers [s]", min_value=0.0, max_value=3600.0, attribute="wait_timeout"
    )
    ack_timeout_s: float = param(
        5.0, "at the end, longest wait for reliable subscribers to acknowledge [s]", min_value=0.0, max_value=600.0,
        attribute="ack_timeout",
    )  # fmt: skip


class BagReplay(Node):
    """Validates a bag, then publishes its messages paced by their log times (see :meth:`replay`)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = declare_config(self, BagReplayConfig)  # also sets self.<name> per parameter
        topics, queue_size = self.config.topics, self.config.queue_size
        if not self.bag:
            raise ValueError("parameter 'bag' is required (a rosbag2 directory or .mcap file)")
        self.path = Path(self.bag).expanduser()

        # validate everything before the first publisher exists: a bad bag publishes nothing
        available = bag_topics(self.path)
        selected = [t.strip() for t in topics.split(",") if t.strip()] or sorted(available)
        unknown = sorted(set(selected) - set(available))
        if unknown:
            raise BagError(f"{self.path}: topic(s) {unknown} are not in the bag; it has {sorted(available)}")
        classes = {}
        for topic in selected:
            try:
                classes[topic] = message_class(available[topic][0])
            except ValueError as exc:
                self.get_logger().warning(f"{topic} skipped: {exc}")
        if not classes:
            raise BagError(f"{self.path}: no topic can be replayed")
        self.topics = sorted(classes)
        t0 = time.monotonic()
        n_messages = sum(1 for _ in read_raw_messages(self.path, self.topics, validate=True))
        if n_messages == 0:
            raise BagError(f"{self.path}: the bag has no messages on {self.topics}")

        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=int(queue_size),
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.VOLATILE,
        )
        self._topic_publishers = {
            topic: self.create_publisher(classes[topic], names.relative(topic), qos) for topic in self.topics
        }
        self.published: Counter[str] = Counter()
        self.passes = 0
        self.get_logger().info(
            f"{self.path}: {n_messages} message(s) on {self.topics} validated in {time.monotonic() - t0:.2f} s; "
            f"rate {self.rate:g}, loop {self.loop}"
        )

    def _sleep(self, executor: SingleThreadedExecutor, seconds: float) -> None:
        """Wait while serving the node's callbacks (parameter services)."""
        deadline = time.monotonic() + seconds
        while (remaining := deadline - time.monotonic()) > 0:
            executor.spin_once(timeout_sec=min(remaining, 0.1))

    def _wait_for_subscribers(self, executor: SingleThreadedExecutor) -> None:
        deadline = time.monotonic() + self.wait_timeout
        while True:
            counts = {t: p.get_subscription_count() for t, p in self._topic_publishers.items()}
            if min(counts.values()) >= self.wait_for_subscribers:
                self._sleep(executor, 0.2)  # let the readers finish matching the writers
                return
            if time.monotonic() >= deadline:
                self.get_logger().warning(
                    f"starting without {self.wait_for_subscribers} subscriber(s) on every topic: {counts}"
                )
                return
            self._sleep(executor, 0.05)

    def replay(self, executor: SingleThreadedExecutor) -> None:
        """Publish the bag once (or until interrupted with ``loop``)."""
        if self.wait_for_subscribers > 0:
            self._wait_for_subscribers(executor)
        if self.start_delay > 0:
            self._sleep(executor, self.start_delay)
        t_start = time.monotonic()
        while True:
            first_ns = None
            pass_start = time.monotonic()
            for msg in read_raw_messages(self.path, self.topics, validate=False):
                if first_ns is None:
                    first_ns = msg.log_time_ns
                due = pass_start + (msg.log_time_ns - first_ns) * 1e-9 / self.rate
                self._sleep(executor, due - time.monotonic())
                self._topic_publishers[msg.topic].publish(msg.data)
                self.published[msg.topic] += 1
            self.passes += 1
            if not self.loop:
                break
        for topic, publisher in self._topic_publishers.items():
            if not publisher.wait_for_all_acked(Duration(seconds=self.ack_timeout)):
                self.get_logger().warning(f"{topic}: not every subscriber acknowledged within {self.ack_timeout:g} s")
        self.get_logger().info(f"done: {self.summary()} in {time.monotonic() - t_start:.2f} s")

    def summary(self) -> str:
        per_topic = ", ".join(f"{topic} {n}" for topic, n in sorted(self.published.items())) or "nothing"
        return f"published {sum(self.published.values())} message(s) in {self.passes} pass(es) ({per_topic})"


def main(args: list[str] | None = None) -> int:
    """Replay the bag; 0 when done or interrupted, 1 on a bad bag or parameters (nothing published)."""

    def replay(node: BagReplay, executor) -> None:
        node.replay(executor)
        if not node.exit_when_done:
            executor.spin()

    return run_node(
        BagReplay, args, threads=1, run=replay, summary=lambda node: node.summary(),
        startup_errors=(BagError, FileNotFoundError, ValueError, ParameterException),
        startup_message="cannot replay the bag (missing, corrupt, truncated or not a rosbag2; nothing was published)",
    )  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
