"""``nbv bench --suite ros_streams`` runs both receivers and reports what each got."""

from __future__ import annotations

import re

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("sensor_msgs")

from nbv_prob_cnn.bench.ros_streams import ros_streams_benchmark  # noqa: E402

pytestmark = pytest.mark.slow  # two receiver processes


def test_both_receivers_get_the_stream(ros_domain) -> None:
    ros_domain(215)
    table = ros_streams_benchmark(rate_hz=100.0, seconds=1.5)  # 150 messages each, as 3 s at 50 Hz
    rows = re.findall(r"^\| (node|stream_node) \| (\d+) \| ([\d.]+) \|", table, re.M)
    assert [r[0] for r in rows] == ["node", "stream_node"], table
    for _, messages, cpu in rows:
        assert 50 <= int(messages) <= 1.5 * 100 + 10 and float(cpu) > 0, table  # most of 1.5 s at 100 Hz, none twice
    assert "node / stream_node" in table
