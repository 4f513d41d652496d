"""``bag_replay``: publish the messages of a rosbag2 on their original topics, paced by bag time.

There is no ``ros2 bag play`` here; this node stands in for it (docs/method.md#node-graph: ``bag_replay`` feeds the
integrator the camera topics of a recorded bag). Messages are published as the serialized CDR
bytes stored in the bag (no decoding), with the publish times following the bag's log times
divided by ``rate``.

The whole bag is validated before anything is published (every message read and, for standard
types, deserialized; counts checked against the bag's index: see
:func:`nbv_prob_cnn.perception.bags.read_raw_messages`). A missing, corrupt or truncated bag is
logged as an error and the node exits with status 1 having published nothing.

Lossless with the defaults of both nodes (``nbv node integrator --ros-args -p pose_source:=topic``
when the bag carries its poses on ``/camera/pose``, the default ``pose_source:=tf`` when on ``/tf``):

* QoS reliable, volatile, depth ``queue_size``; ``/tf`` and ``/tf_static`` with tf2's QoS and
  their absolute names, as a robot's drivers publish them (``/tf_static`` transient local: a
  volatile writer would match no TF listener). Messages published before a subscriber is
  matched would be lost (volatile), so the replay first waits until every topic has
  ``wait_for_subscribers`` (default 1) matched subscribers; after ``wait_timeout_s`` without
  them it logs an error naming the topics and exits with status 1, having published nothing
  (``wait_for_subscribers:=0`` publishes regardless).
* ``pace_by_integrator`` (default true): first the replay waits until the integrator's own
  subscriptions report a matched publisher on the replayed topics (``inputs`` of its
  diagnostics; matching happens on each side on its own). Then, before each depth image (``/camera/depth/image``) the
  replay waits until the integrator (its ``integrator/diagnostics`` service, in the node's
  namespace) has received every image sent so far and has none pending (each one integrated or
  dropped under a reason), at most ``frame_timeout_s`` per frame. A slow or loaded integrator
  thus slows the replay down instead of losing frames: the integrator's default best-effort
  subscriptions (depth 5) and ``drop_when_behind`` never see more than one frame at a time, and
  frames are integrated in bag order (the grid equals ``nbv integrate`` of the bag). Without that
  service (another consumer), the replay is paced by bag time only, with a warning.
* At the end it logs ``sent N, integrated M, dropped K by reason (...); received R`` (the
  integrator's counts since the replay started; images sent but never received are named as such
  with the DDS-reported transport losses).

When the bag is done (``loop:=false``) the node waits until reliable subscribers acknowledged
everything (at most ``ack_timeout_s``), logs the summary and exits with status 0; with
``exit_when_done:=false`` it keeps running (publishers alive) until interrupted.

Run: ``nbv node bag_replay --ros-args -p bag:=bags/3dt_seed1000_sample -p rate:=2.0``
"""

from __future__ import annotations

import importlib
import json
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from nbv_prob_cnn.perception.bags import TOPIC_IMAGE, BagError, bag_topics, read_raw_messages
from nbv_prob_cnn.perception.replay_accounting import ReplayDelta, replay_delta, replay_line
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.parameters import declare_config, param
from nbv_prob_cnn.ros.runtime import run_node
from nbv_prob_cnn.ros.tf_listener import TF_QOS, TF_STATIC_QOS, TOPIC_TF, TOPIC_TF_STATIC

NODE_NAME = "bag_replay"
#: A diagnostics request not answered in this time is sent again (a request sent right after the
#: service appeared can be lost while DDS matches the reply reader) [s].
DIAGNOSTICS_RESEND_S = 1.0
#: Poll period of the integrator's diagnostics while waiting for a frame [s].
PACE_POLL_S = 0.005


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
    start_delay_s: float = param(0.0, "wait this long before the first message [s]", min_value=0.0, max_value=3600.0)
    exit_when_done: bool = param(True, "exit (status 0) after the last message; false: keep running")
    topics: str = param("", "comma-separated topics to replay; empty = every topic of the bag")
    queue_size: int = param(10, "publisher history depth", min_value=1, max_value=10000)
    wait_for_subscribers: int = param(
        1, "before starting, wait until every topic has this many matched subscribers (0 = publish regardless)",
        min_value=0, max_value=1000,
    )  # fmt: skip
    wait_timeout_s: float = param(
        30.0, "longest wait for subscribers (then exit 1, nothing published) and the integrator's diagnostics [s]",
        min_value=0.0, max_value=3600.0,
    )  # fmt: skip
    pace_by_integrator: bool = param(
        True, "before each depth image, wait until the integrator (integrator/diagnostics) received every image "
        "sent and has none pending (lossless with a slow integrator); false: bag time only",
    )  # fmt: skip
    frame_timeout_s: float = param(
        10.0, "pace_by_integrator: longest wait for the integrator to finish one frame (then go on, with a "
        "warning) [s]", min_value=0.01, max_value=600.0,
    )  # fmt: skip
    ack_timeout_s: float = param(
        5.0, "at the end, longest wait for reliable subscribers to acknowledge [s]", min_value=0.0, max_value=600.0,
    )  # fmt: skip


class BagReplay(Node):
    """Validates a bag, then publishes its messages paced by their log times (see :meth:`replay`)."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = declare_config(self, BagReplayConfig, mirror=False)
        topics, queue_size = self.config.topics, self.config.queue_size
        if not self.config.bag:
            raise ValueError("parameter 'bag' is required (a rosbag2 directory or .mcap file)")
        self.path = Path(self.config.bag).expanduser()

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
        self._topic_publishers = {}
        for topic in self.topics:
            # /tf and /tf_static as tf2 publishes them: absolute names, tf2's QoS
            profile = TF_QOS if topic == TOPIC_TF else TF_STATIC_QOS if topic == TOPIC_TF_STATIC else qos
            topic_name = topic if topic in (TOPIC_TF, TOPIC_TF_STATIC) else names.relative(topic)
            self._topic_publishers[topic] = self.create_publisher(classes[topic], topic_name, profile)
        self.published: Counter[str] = Counter()
        self.passes = 0
        self.frames_sent = 0  # depth images published
        self._diagnostics = self.create_client(Trigger, names.INTEGRATOR_DIAGNOSTICS)
        self._baseline: dict | None = None  # the integrator's report before the first frame
        self.delta: ReplayDelta | None = None  # its counts since then (latest report)
        self.late_frames = 0  # frames the integrator had not finished within frame_timeout_s
        self.get_logger().info(
            f"{self.path}: {n_messages} message(s) on {self.topics} validated in {time.monotonic() - t0:.2f} s; "
            f"rate {self.config.rate:g}, loop {self.config.loop}"
        )

    def _sleep(self, executor: SingleThreadedExecutor, seconds: float) -> None:
        """Wait while serving the node's callbacks (parameter services)."""
        deadline = time.monotonic() + seconds
        while (remaining := deadline - time.monotonic()) > 0:
            executor.spin_once(timeout_sec=min(remaining, 0.1))

    def _wait_for_subscribers(self, executor: SingleThreadedExecutor) -> None:
        """Wait until every topic has ``wait_for_subscribers`` matched subscriptions.

        Raises:
            TimeoutError: not within ``wait_timeout_s`` (nothing has been published).
        """
        wanted, timeout_s = self.config.wait_for_subscribers, self.config.wait_timeout_s
        deadline = time.monotonic() + timeout_s
        while True:
            counts = {t: p.get_subscription_count() for t, p in self._topic_publishers.items()}
            if min(counts.values()) >= wanted:
                self._sleep(executor, 0.2)  # let the readers finish matching the writers
                return
            if time.monotonic() >= deadline:
                short = {t: n for t, n in counts.items() if n < wanted}
                raise TimeoutError(
                    f"after {timeout_s:g} s, fewer than {wanted} subscriber(s) on "
                    f"{short}: start the integrator first (or set wait_for_subscribers:=0 to publish regardless)"
                )
            self._sleep(executor, 0.05)

    def _integrator_report(self, executor: SingleThreadedExecutor, timeout_s: float) -> dict | None:
        """The integrator's diagnostics (the JSON of its Trigger answer), None when none in time."""
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            future = self._diagnostics.call_async(Trigger.Request())
            executor.spin_until_future_complete(future, timeout_sec=min(DIAGNOSTICS_RESEND_S, remaining))
            if future.done() and future.result() is not None:
                try:
                    return json.loads(future.result().message)
                except ValueError:
                    self.get_logger().warning(f"{self._diagnostics.srv_name}: the answer is not JSON")
                    return None
            self._diagnostics.remove_pending_request(future)
        return None

    def _start_pacing(self, executor: SingleThreadedExecutor) -> None:
        """Take the integrator's counts before the first frame (or warn that there is none)."""
        name = self.resolve_service_name(self._diagnostics.srv_name)
        if self._diagnostics.wait_for_service(timeout_sec=self.config.wait_timeout_s):
            self._baseline = self._readers_matched(
                executor, self._integrator_report(executor, self.config.wait_timeout_s)
            )
        if self._baseline is None:
            self.get_logger().warning(
                f"no integrator diagnostics at {name} within {self.config.wait_timeout_s:g} s: paced by bag time only, "
                "frames lost by a slow receiver cannot be seen (pace_by_integrator:=false silences this)"
            )
        else:
            self.get_logger().info(f"pacing by {name}: each depth image waits until the integrator finished the last")

    def _readers_matched(self, executor: SingleThreadedExecutor, report: dict | None) -> dict | None:
        """The integrator's report once its subscriptions of the replayed topics have matched a
        publisher (its ``inputs``; at most ``wait_timeout_s``): that the replay's writers matched
        them is not enough, a reader that has not matched the writer yet drops what it sends."""
        topics = {self.resolve_topic_name(names.relative(t)) for t in self.topics}
        deadline = time.monotonic() + self.config.wait_timeout_s
        while report is not None:
            inputs = report.get("inputs", {})
            waiting = sorted(t for t in topics & set(inputs) if inputs[t].get("matched", 0) < 1)
            if not waiting:
                return report
            if time.monotonic() >= deadline:
                self.get_logger().warning(f"the integrator has not matched a publisher on {waiting}; starting anyway")
                return report
            self._sleep(executor, 0.05)
            report = self._integrator_report(executor, max(deadline - time.monotonic(), DIAGNOSTICS_RESEND_S))
        return report

    def _update_delta(self, executor: SingleThreadedExecutor, timeout_s: float) -> ReplayDelta | None:
        assert self._baseline is not None
        report = self._integrator_report(executor, timeout_s)
        if report is not None:
            self.delta = replay_delta(self._baseline, report)
        return self.delta if report is not None else None

    def _wait_for_integrator(self, executor: SingleThreadedExecutor) -> None:
        """Wait until the integrator received every image sent and has none pending."""
        if self._baseline is None or self.frames_sent == 0:
            return
        deadline = time.monotonic() + self.config.frame_timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            delta = self._update_delta(executor, remaining)
            if delta is not None and delta.received >= self.frames_sent and delta.pending == 0:
                return
            self._sleep(executor, min(PACE_POLL_S, max(deadline - time.monotonic(), 0.0)))
        self.late_frames += 1
        got = f"received {self.delta.received}, pending {self.delta.pending}" if self.delta else "no answer"
        self.get_logger().warning(
            f"frame {self.frames_sent}: the integrator did not finish it within {self.config.frame_timeout_s:g} s "
            f"({got}); going on", throttle_duration_sec=5.0,
        )  # fmt: skip

    def replay(self, executor: SingleThreadedExecutor) -> None:
        """Publish the bag once (or until interrupted with ``loop``).

        Raises:
            TimeoutError: no subscribers within ``wait_timeout_s`` (nothing published).
        """
        if self.config.wait_for_subscribers > 0:
            self._wait_for_subscribers(executor)
        if self.config.pace_by_integrator:
            self._start_pacing(executor)
        if self.config.start_delay_s > 0:
            self._sleep(executor, self.config.start_delay_s)
        t_start = time.monotonic()
        while True:
            first_ns = None
            pass_start = time.monotonic()
            for msg in read_raw_messages(self.path, self.topics, validate=False):
                if first_ns is None:
                    first_ns = msg.log_time_ns
                is_frame = msg.topic == TOPIC_IMAGE
                if is_frame:
                    self._wait_for_integrator(executor)  # the previous frame first (no-op unless pacing)
                due = pass_start + (msg.log_time_ns - first_ns) * 1e-9 / self.config.rate
                self._sleep(executor, due - time.monotonic())
                self._topic_publishers[msg.topic].publish(msg.data)
                self.published[msg.topic] += 1
                self.frames_sent += int(is_frame)
            self.passes += 1
            if not self.config.loop:
                break
        for topic, publisher in self._topic_publishers.items():
            if not publisher.wait_for_all_acked(Duration(seconds=self.config.ack_timeout_s)):
                self.get_logger().warning(
                    f"{topic}: not every subscriber acknowledged within {self.config.ack_timeout_s:g} s"
                )
        if self._baseline is not None:
            self._wait_for_integrator(executor)
            self._sleep(executor, 0.1)  # drops are counted just after the frame leaves the pending set
            self._update_delta(executor, self.config.wait_timeout_s)
        self.get_logger().info(f"done: {self.summary()} in {time.monotonic() - t_start:.2f} s")

    def summary(self) -> str:
        per_topic = ", ".join(f"{topic} {n}" for topic, n in sorted(self.published.items())) or "nothing"
        late = f"; {self.late_frames} frame(s) not finished within frame_timeout_s" if self.late_frames else ""
        return (
            f"{replay_line(self.frames_sent, self.delta if self._baseline is not None else None)}{late}; "
            f"published {sum(self.published.values())} message(s) in {self.passes} pass(es) ({per_topic})"
        )


def main(args: list[str] | None = None) -> int:
    """Replay the bag; 0 when done or interrupted, 1 on a bad bag or parameters (nothing published)."""

    def replay(node: BagReplay, executor) -> None:
        node.replay(executor)
        if not node.config.exit_when_done:
            executor.spin()

    return run_node(
        BagReplay, args, threads=1, run=replay, summary=lambda node: node.summary(),
        startup_errors=(BagError, FileNotFoundError, ValueError, ParameterException, TimeoutError),
        startup_message="cannot replay the bag (missing, corrupt, truncated or not a rosbag2; nothing was published)",
    )  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
