"""The inputs every planning node shares, without a ROS graph (a stand-in node records what they
create): :class:`~nbv_prob_cnn.ros.grid_holder.LatestGrid` keeps the newest grid and wakes the
waits for a newer one; :class:`~nbv_prob_cnn.ros.joint_state_intake.JointStateIntake` merges
joint states, logs the malformed ones and hands on each complete configuration."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")

from nbv_prob_cnn_msgs.msg import CompressedVoxelGrid, VoxelGrid  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.basics.interrupt import Interrupt, WaitInterruptedError  # noqa: E402
from nbv_prob_cnn.ros import names  # noqa: E402
from nbv_prob_cnn.ros.conversions import compress_grid_msg, grid_to_msg, msg_to_grid, time_msg  # noqa: E402
from nbv_prob_cnn.ros.grid_holder import LatestGrid  # noqa: E402
from nbv_prob_cnn.ros.joint_state_intake import ERROR_LOG_PERIOD_S, JointStateIntake  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

LONG_S = 30.0  # a timeout no test may wait out


class RecordingNode:
    """Stands in for an rclpy node: records subscriptions and error logs."""

    def __init__(self) -> None:
        self.subscriptions: list[tuple] = []
        self.errors: list[tuple[str, dict]] = []

    def create_subscription(self, msg_type, topic, callback, qos, **kwargs):
        self.subscriptions.append((msg_type, topic, callback, qos, kwargs))

    def get_logger(self):
        return self

    def error(self, text: str, **kwargs) -> None:
        self.errors.append((text, kwargs))


def grid_at(sec: int) -> VoxelGrid:
    msg = VoxelGrid()
    msg.header.stamp.sec = sec
    return msg


def test_latest_grid_reads_the_compressed_topic_and_refuses_bad_grids() -> None:
    node, seen = RecordingNode(), []
    grids = LatestGrid(node, on_grid=seen.append, transport="compressed")  # type: ignore[arg-type]
    [(msg_type, topic, callback, qos, _)] = node.subscriptions
    assert (msg_type, topic, qos) == (CompressedVoxelGrid, names.GRID_COMPRESSED, GRID_QOS)
    with pytest.raises(ValueError, match="no grid received yet on /nbv/grid/compressed"):
        grids.latest()
    state = np.full((6, 5, 4), -1, np.int8)
    state[:, :, :2] = 0
    state[1, 2, 1] = 1
    raw = grid_to_msg(state, GridGeometry((0.0, 0.0, 0.0), 0.05, state.shape), "world", time_msg(3_000_000_000))
    callback(compress_grid_msg(raw))
    assert grids.latest() == raw and seen == [grids.latest()]
    assert np.array_equal(msg_to_grid(grids.wait_for_stamp(3_000_000_000, 0.05))[0], state)
    bad = compress_grid_msg(grid_at(4))
    bad.format = "png"
    callback(bad)  # logged and counted; the newest good grid stays
    assert grids.refused == 1 and grids.latest() == raw and len(seen) == 1
    [(text, _)] = node.errors
    assert text.startswith("nbv/grid/compressed: grid refused (1 so far): compressed grid: format 'png'")
    with pytest.raises(ValueError, match="grid_transport: 'theora' is not one of \\['raw', 'compressed'\\]"):
        LatestGrid(node, transport="theora")  # type: ignore[arg-type]


def test_latest_grid_keeps_the_newest_and_waits_for_a_stamp() -> None:
    node, seen = RecordingNode(), []
    group = object()
    grids = LatestGrid(node, callback_group=group, on_grid=seen.append)  # type: ignore[arg-type]
    [(msg_type, topic, callback, qos, kwargs)] = node.subscriptions
    assert (msg_type, topic, qos, kwargs) == (VoxelGrid, names.GRID, GRID_QOS, {"callback_group": group})
    with pytest.raises(ValueError, match="no grid received yet on /nbv/grid"):
        grids.latest()
    with pytest.raises(TimeoutError, match="no grid including the frame at 0 ns within 0 s"):
        grids.wait_for_stamp(0, 0.05)

    first = grid_at(1)
    callback(first)
    assert grids.latest() is first and seen == [first]
    assert grids.wait_for_stamp(1_000_000_000, 0.05) is first  # already there: no wait
    with pytest.raises(TimeoutError, match="no grid including the frame at 1000000001 ns"):
        grids.wait_for_stamp(1_000_000_001, 0.05)

    newer = grid_at(2)
    arrival = threading.Timer(0.1, callback, (newer,))
    arrival.start()
    start = time.monotonic()
    assert grids.wait_for_stamp(1_500_000_000, LONG_S) is newer  # woken by the arrival, not the timeout
    assert time.monotonic() - start < 5.0
    arrival.join()
    assert grids.latest() is newer and seen == [first, newer]

    interrupt = Interrupt()
    trigger = threading.Timer(0.1, interrupt.trigger, ("goal canceled",))
    trigger.start()
    start = time.monotonic()
    with pytest.raises(WaitInterruptedError, match="goal canceled"):
        grids.wait_for_stamp(3_000_000_000, LONG_S, interrupt)
    assert time.monotonic() - start < 5.0
    trigger.join()


def joint_state(joint_names, positions) -> JointState:
    return JointState(name=list(joint_names), position=[float(v) for v in positions])


def test_joint_state_intake_logs_bad_states_and_hands_on_complete_ones(robot) -> None:
    node, side, configurations = RecordingNode(), RecordingNode(), []
    intake = JointStateIntake(robot, node, side, configurations.append)  # type: ignore[arg-type]
    assert node.subscriptions == []  # subscribed on the side node
    [(msg_type, topic, callback, depth, _)] = side.subscriptions
    assert (msg_type, topic, depth) == (JointState, names.JOINT_STATES, 10)

    q = robot.reference_q + 0.05
    callback(joint_state(robot.joint_names[:2], q[:2]))  # the first joints alone: not complete yet
    assert configurations == [] and node.errors == []
    callback(joint_state(robot.joint_names[2:], q[2:]))  # the rest (as a gripper driver would publish)
    assert len(configurations) == 1
    np.testing.assert_array_equal(configurations[0], q)
    np.testing.assert_array_equal(intake.current()[0], q)

    callback(joint_state(robot.joint_names[:2], [0.0]))  # malformed: logged, not handed on
    assert node.errors == [("joint_states: 2 joint names but 1 positions",
                            {"throttle_duration_sec": ERROR_LOG_PERIOD_S})]  # fmt: skip
    assert len(configurations) == 1
    with pytest.raises(ValueError, match="2 joint names but 1 positions"):
        intake.current()

    without_hook = JointStateIntake(robot, node)  # type: ignore[arg-type]
    assert node.subscriptions[0][1] == names.JOINT_STATES  # default: on the node itself
    node.subscriptions[0][2](joint_state(robot.joint_names, q))
    np.testing.assert_array_equal(without_hook.current()[0], q)
