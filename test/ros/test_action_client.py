"""LockedActionClient (nbv_prob_cnn.ros.action_client): an answer taken by another executor thread
between the send and the filing of its future is still matched. The race is forced: the client's
send waits, after sending, until an executor thread has taken the server's answer.

With rclpy's own ActionClient the same test fails: the answer is dropped with "Ignoring unexpected
goal response" and the goal future never completes (checked by hand with rclpy 7.1.6)."""

from __future__ import annotations

import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from nbv_prob_cnn_msgs.action import Explore  # noqa: E402
from rclpy.action import ActionServer, GoalResponse  # noqa: E402
from rclpy.callback_groups import ReentrantCallbackGroup  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402

from nbv_prob_cnn.ros.action_client import LockedActionClient  # noqa: E402

pytestmark = pytest.mark.slow  # a ROS node (in this process)


class SlowHandle:
    """The client's rcl handle, whose sends return only once the answer has been taken (the
    sending thread descheduled right after the send, as on a loaded machine)."""

    def __init__(self, handle, taken: dict[str, threading.Event]) -> None:
        self._handle, self._taken = handle, taken

    def __getattr__(self, name):
        return getattr(self._handle, name)

    def __enter__(self):
        return self._handle.__enter__()

    def __exit__(self, *exc):
        return self._handle.__exit__(*exc)

    def _slow(self, kind: str, send, request):
        self._taken[kind].clear()
        sequence = send(request)
        assert self._taken[kind].wait(10.0), f"no {kind} answer taken within 10 s"
        time.sleep(0.2)  # a plain ActionClient drops the answer here
        return sequence

    def send_goal_request(self, request):
        return self._slow("goal", self._handle.send_goal_request, request)

    def send_result_request(self, request):
        return self._slow("result", self._handle.send_result_request, request)


class ProbedClient(LockedActionClient):
    """Marks when an executor thread has taken a goal or result answer."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.taken = {"goal": threading.Event(), "result": threading.Event()}
        self._client_handle = SlowHandle(self._client_handle, self.taken)

    async def execute(self, taken_data):
        for kind in self.taken:
            if kind in taken_data:
                self.taken[kind].set()
        return await super().execute(taken_data)


def test_answers_taken_before_the_future_is_filed_are_matched(ros_domain):
    ros_domain(141)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("locked_action_client_test", context=context)
    group = ReentrantCallbackGroup()

    def execute(handle):
        handle.succeed()
        return Explore.Result(views=7)

    server = ActionServer(node, Explore, "/explore_probe", execute_callback=execute,
                          goal_callback=lambda _goal: GoalResponse.ACCEPT, callback_group=group)  # fmt: skip
    client = ProbedClient(node, Explore, "/explore_probe", callback_group=group)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        assert client.wait_for_server(timeout_sec=30.0)
        goal_future = client.send_goal_async(Explore.Goal(max_views=1))
        deadline = time.monotonic() + 10.0
        while not goal_future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert goal_future.done(), "the goal's answer was dropped"
        handle = goal_future.result()
        assert handle.accepted
        result_future = handle.get_result_async()
        deadline = time.monotonic() + 10.0
        while not result_future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert result_future.done(), "the result's answer was dropped"
        assert result_future.result().result.views == 7
    finally:
        executor.shutdown()
        client.destroy()
        server.destroy()
        node.destroy_node()
        rclpy.shutdown(context=context)
