"""rclpy's ``ActionClient`` without its lost-answer race (rclpy 7.1, Jazzy).

``ActionClient.send_goal_async`` sends the goal request first and only then files the future that
its answer completes, under the request's sequence number; ``get_result_async`` and
``cancel_goal_async`` do the same. When another thread of a multi-threaded executor takes the
answer in between (a fast server on a loaded machine: the sending thread is descheduled right
after the send), the client logs "Ignoring unexpected goal response. There may be more than one
action server" and drops the answer: the server runs the goal while the client waits for an
acceptance that never comes. The suite met it as a trajectory goal re-planned after 30 s
(a second FollowJointTrajectory goal for one view, at load 10) and Explore goals without an answer.

:class:`LockedActionClient` holds a lock from before each send until its future is filed, and its
``execute`` (where answers are matched to futures) waits for that lock before matching, so an
answer is matched only once its future is filed. The lock is not held while user callbacks
(feedback) run. Later rclpy releases close the race the same way inside ``ActionClient``.
"""

from __future__ import annotations

import threading

from rclpy.action import ActionClient


class LockedActionClient(ActionClient):
    """An ``ActionClient`` whose goal, result and cancel answers are never matched before their
    request's future is filed (see the module docstring); otherwise the same."""

    def __init__(self, *args, **kwargs) -> None:
        self._send_lock = threading.Lock()
        super().__init__(*args, **kwargs)

    def send_goal_async(self, *args, **kwargs):
        with self._send_lock:
            return super().send_goal_async(*args, **kwargs)

    def _get_result_async(self, goal_handle):
        with self._send_lock:
            return super()._get_result_async(goal_handle)

    def _cancel_goal_async(self, goal_handle):
        with self._send_lock:
            return super()._cancel_goal_async(goal_handle)

    async def execute(self, taken_data):
        with self._send_lock:  # a send whose answer was taken has filed its future once this is free
            pass
        return await super().execute(taken_data)


__all__ = ["LockedActionClient"]
