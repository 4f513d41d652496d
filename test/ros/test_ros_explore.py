"""The Explore action of ``nbv_planner`` (one process) against a stand-in camera in the test
process: goal states match what happened (succeeded, canceled, aborted), one exploration at a
time (a second goal is rejected), bad goals are refused, and the server keeps serving after each case."""

from __future__ import annotations

import contextlib
import os
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from action_msgs.msg import GoalStatus  # noqa: E402
from nbv_prob_cnn_msgs.action import Explore  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import MoveCamera  # noqa: E402
from rclpy.callback_groups import ReentrantCallbackGroup  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.ros.action_client import LockedActionClient  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, send_goal_with_resend  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

GEOMETRY = GridGeometry((0.0, 0.0, 0.0), 0.02, (24, 24, 24))
_counter = iter(range(1000))


def small_grid() -> np.ndarray:
    state = np.full(GEOMETRY.shape, -1, dtype=np.int8)
    state[6:18, 6:18, 6:18] = 0  # known empty room in unknown space: every view there has gain
    return state


class FakeCamera:
    """``/sim_camera/move_to`` that takes ``delay_s``, then publishes the (unchanged) grid
    stamped with the new frame's time; ``fail`` makes the move fail."""

    def __init__(self, node, delay_s: float = 0.3) -> None:
        self.node, self.delay_s, self.fail, self.moves = node, delay_s, False, 0
        self.publisher = node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS)
        self.state = small_grid()
        self.publish()
        node.create_service(MoveCamera, "/sim_camera/move_to", self.move, callback_group=ReentrantCallbackGroup())

    def publish(self):
        msg = grid_to_msg(self.state, GEOMETRY)
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.publisher.publish(msg)
        return msg.header.stamp

    def move(self, request, response):
        time.sleep(self.delay_s)
        if self.fail:
            response.success, response.message = False, "arm in collision"
            return response
        self.moves += 1
        response.frame_stamp = self.publish()
        response.success = True
        return response


@contextlib.contextmanager
def spun_node(name: str):
    """A client node of the test process in its own context, spun by a 4-thread executor in a
    background thread; shut down (node, context, thread) on exit."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(name, context=context)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield node
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=5)


@pytest.fixture
def explore_graph(tmp_path, ros_domain):
    domain = 101 + (os.getpid() + next(_counter)) % 9  # 101..109: no other test module uses these
    env = ros_domain(domain)
    with spun_node("explore_test") as node:
        camera = FakeCamera(node)
        graph = NodeGraph(env, log_dir=tmp_path / "logs")
        graph.start_node(
            "nbv_planner",
            "nbv_planner",
            {"dataset": "3du", "method": "prob_ig", "in_process": True, "backend": "numpy", "markers_top_k": 1},
        )
        client = LockedActionClient(node, Explore, "/nbv/explore")
        assert client.wait_for_server(timeout_sec=60.0), "the Explore server did not come up"
        yield client, camera, graph
        graph.stop()


def wait(future, timeout_s: float = 60.0):
    deadline = time.monotonic() + timeout_s
    while not future.done() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert future.done(), "no answer in time"
    return future.result()


def send(client, goal: Explore.Goal, feedback: list | None = None):
    """The goal's handle; the goal is sent again (same ID) while no answer comes: the planner's
    answer to a client it has not matched yet is dropped ("failed to send response (timeout)")."""
    callback = feedback.append if feedback is not None else None
    return send_goal_with_resend(client, goal, 60.0, feedback_callback=callback, resend_s=5.0)


def test_explore_goal_states_match_what_happened(explore_graph):
    client, camera, graph = explore_graph

    # a normal run ends SUCCEEDED when it reaches its view budget
    feedback: list = []
    handle = send(client, Explore.Goal(max_views=2), feedback)
    assert handle.accepted
    done = wait(handle.get_result_async())
    assert done.status == GoalStatus.STATUS_SUCCEEDED, done.result.reason_stopped
    assert done.result.views == 2 and "reached 2 views" in done.result.reason_stopped
    assert camera.moves == 2
    # without a surface stop rule no estimate is made (NaN); with one, each view carries it
    assert len(feedback) == 2 and all(np.isnan(f.feedback.new_surface_cells) for f in feedback)
    handle = send(client, Explore.Goal(max_views=1, stop_new_surface_cells=1e-3), feedback := [])
    done = wait(handle.get_result_async())
    assert done.status == GoalStatus.STATUS_SUCCEEDED and done.result.views == 1, done.result.reason_stopped
    assert len(feedback) == 1 and np.isfinite(feedback[0].feedback.new_surface_cells)
    assert feedback[0].feedback.new_surface_cells >= 1e-3
    moved = camera.moves

    # the surface stop rule: no view is expected to add 1e9 surface cells, so the first planned
    # view already ends the exploration, SUCCEEDED, with the reason
    handle = send(client, Explore.Goal(max_views=5, stop_new_surface_cells=1e9))
    done = wait(handle.get_result_async())
    assert done.status == GoalStatus.STATUS_SUCCEEDED, done.result.reason_stopped
    assert done.result.views == 0 and done.result.reason_stopped.startswith("surface finished")
    assert camera.moves == moved
    assert not send(client, Explore.Goal(max_views=3, stop_new_surface_share=-1.0)).accepted

    # 0 views and non-finite thresholds are refused; a negative count cannot even be sent: the
    # client's serialisation of the uint32 field fails before anything reaches the server
    assert not send(client, Explore.Goal(max_views=0)).accepted
    assert not send(client, Explore.Goal(max_views=3, stop_gain=float("nan"))).accepted
    with pytest.raises((SystemError, OverflowError, ValueError)):
        client.send_goal_async(Explore.Goal(max_views=-1))

    # two goals at once: the second is rejected in the goal response, the first one is not
    # disturbed; canceling the first mid-run ends it CANCELED after the views it took
    first = send(client, Explore.Goal(max_views=1000), feedback := [])
    assert first.accepted and not send(client, Explore.Goal(max_views=2)).accepted
    deadline = time.monotonic() + 60
    while len(feedback) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(feedback) >= 2, "the first exploration stopped making progress"
    wait(first.cancel_goal_async())
    first_done = wait(first.get_result_async())
    assert first_done.status == GoalStatus.STATUS_CANCELED
    assert "canceled" in first_done.result.reason_stopped and 2 <= first_done.result.views < 1000

    # an error (the camera cannot move) ends ABORTED with the reason, never SUCCEEDED
    camera.fail = True
    failed = wait(send(client, Explore.Goal(max_views=3)).get_result_async())
    assert failed.status == GoalStatus.STATUS_ABORTED
    assert "arm in collision" in failed.result.reason_stopped and failed.result.views == 0

    # the same server still explores after every case
    camera.fail = False
    again = wait(send(client, Explore.Goal(max_views=1)).get_result_async())
    assert again.status == GoalStatus.STATUS_SUCCEEDED and again.result.views == 1
    assert graph.alive() == {"nbv_planner": True}
