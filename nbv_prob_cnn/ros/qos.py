"""QoS of our topics: the grid's latched profile and the input subscriptions' profile, with a
count of the messages DDS reports lost."""

from __future__ import annotations

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

#: The grid topic keeps its last message for late joiners and restarted nodes.
GRID_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: Reliability names of :func:`subscription_qos` (``best_effort`` with depth 5 is SENSOR_DATA).
RELIABILITY = ("best_effort", "reliable")


def subscription_qos(depth: int, reliability: str) -> QoSProfile:
    """A volatile keep-last QoS profile for input subscriptions.

    Raises:
        ValueError: an unknown reliability name.
    """
    if reliability not in RELIABILITY:
        raise ValueError(f"qos_reliability: expected one of {list(RELIABILITY)}, got {reliability!r}")
    return QoSProfile(
        depth=int(depth),
        reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def lost_message_counter(node, counts: dict[str, int], topic: str) -> SubscriptionEventCallbacks:
    """Event callbacks of a subscription that keep ``counts[topic]`` at the number of its messages
    DDS reports lost before delivery (a gap in a best-effort writer's sequence numbers, or samples a
    reliable writer gave up on), and log each new loss (at most every 5 s)."""
    counts[topic] = 0

    def on_lost(status) -> None:
        counts[topic] = int(status.total_count)
        node.get_logger().warning(
            f"{topic}: {status.total_count_change} message(s) lost in transport (DDS); "
            f"{status.total_count} so far", throttle_duration_sec=5.0,
        )  # fmt: skip

    return SubscriptionEventCallbacks(message_lost=on_lost)
