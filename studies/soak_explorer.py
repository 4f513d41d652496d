"""The exploring client of ``nbv study soak``: until a set time (and at least once, as the
requester sends its first round whatever the time), resets the integrator and runs one Explore
goal after another; every exploration (and, at the end, the integrator's diagnostics) is
one JSON line of its event log. Run by :mod:`studies.soak` as its own process:
``nbv study soak_explorer --until EPOCH --events FILE``."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import rclpy
from action_msgs.msg import GoalStatus
from nbv_prob_cnn_msgs.action import Explore
from nbv_prob_cnn_msgs.msg import VoxelGrid
from std_srvs.srv import Trigger

from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.graph import call_with_resend
from nbv_prob_cnn.ros.qos import GRID_QOS
from studies._soak_client import SoakClient, client_parser, run_session

STATUS_NAMES = {GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_CANCELED: "canceled",
                GoalStatus.STATUS_ABORTED: "aborted"}  # fmt: skip


class SoakExplorer(SoakClient):
    """Explores again and again, with the integrator reset before each exploration."""

    def __init__(self, events: Path) -> None:
        super().__init__("soak_explorer", events)
        self._reset = self.create_client(Trigger, names.INTEGRATOR_RESET)
        self._diagnostics = self.create_client(Trigger, names.INTEGRATOR_DIAGNOSTICS)
        self._goal = None
        self._grid_stamp: tuple[int, int] | None = None  # header stamp of the latest grid
        self._grids = 0
        self.create_subscription(VoxelGrid, names.GRID, self._on_grid, GRID_QOS)

    def _on_grid(self, msg: VoxelGrid) -> None:
        self._grid_stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        self._grids += 1

    def wait_for_frame(self, timeout_s: float) -> bool:
        """Wait for a grid with an integrated frame (after a reset the grid is stamped 0 and
        all unknown: an exploration would stop at once, with no view of positive gain)."""
        seen = self._grids
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.executor_.spin_once(timeout_sec=0.1)
            if self._grids > seen and self._grid_stamp not in (None, (0, 0)):
                return True
        return False

    def wait_ready(self, timeout_s: float) -> bool:
        return self._action.wait_for_server(timeout_sec=timeout_s)

    def explore_once(self, views: int, method: str, timeout_s: float) -> int:
        """One exploration after a reset; returns the views it took (0 when it ended without one)."""
        start = time.time()
        reset = call_with_resend(self._reset, Trigger.Request(), 60.0, executor=self.executor_)
        fresh = self.wait_for_frame(30.0)
        self.log_event(event="reset", success=reset.success, message=reset.message, frame_after_reset=fresh)
        goal = Explore.Goal(method=method, max_views=views)
        send = self._action.send_goal_async(goal)
        self.executor_.spin_until_future_complete(send, timeout_sec=60.0)
        handle = send.result() if send.done() else None
        if handle is None or not handle.accepted:
            self.log_event(event="exploration", start_wall=start, end_wall=time.time(), status="rejected",
                           views=0, reason="goal rejected or not answered")  # fmt: skip
            time.sleep(1.0)
            return 0
        self._goal = handle
        result = handle.get_result_async()
        self.executor_.spin_until_future_complete(result, timeout_sec=timeout_s)
        self._goal = None
        if not result.done():
            self.log_event(event="exploration", start_wall=start, end_wall=time.time(), status="timeout",
                           views=0, reason=f"no result within {timeout_s:g} s")  # fmt: skip
            handle.cancel_goal_async()
            return 0
        answer = result.result()
        unknown = float(answer.result.final_unknown_fraction)
        self.log_event(
            event="exploration", start_wall=start, end_wall=time.time(),
            status=STATUS_NAMES.get(answer.status, str(answer.status)), views=int(answer.result.views),
            final_unknown_fraction=unknown if math.isfinite(unknown) else None,
            reason=answer.result.reason_stopped, failed_executions=int(answer.result.failed_executions),
        )  # fmt: skip
        return int(answer.result.views)

    def cancel(self) -> None:
        if self._goal is not None:
            future = self._goal.cancel_goal_async()
            self.executor_.spin_until_future_complete(future, timeout_sec=5.0)

    def final_diagnostics(self) -> None:
        reply = call_with_resend(self._diagnostics, Trigger.Request(), 30.0, executor=self.executor_)
        self.log_event(event="diagnostics", report=json.loads(reply.message))


def main(argv: list[str] | None = None) -> int:
    parser = client_parser("Explore again and again until --until (nbv study soak).",
                           "stop starting explorations then (epoch s)")  # fmt: skip
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--method", default="")
    parser.add_argument("--timeout", type=float, default=600.0, help="longest exploration [s]")
    parser.add_argument("--ready-timeout", type=float, default=120.0)
    parser.add_argument("--first-tries", type=int, default=3,
                        help="explorations tried for a first one with a view, whatever --until")  # fmt: skip
    args = parser.parse_args(argv)
    rclpy.init()
    node = SoakExplorer(args.events)

    def explore() -> int:
        try:
            if not node.wait_ready(args.ready_timeout):
                node.log_event(event="error", message=f"no Explore server within {args.ready_timeout:g} s")
                return 1
            node.log_event(event="ready")
            # at least one exploration with a view, however short the soak: the requester's own
            # integrator_reset can empty the grid under the first one, which then ends at once
            # without a view (its reason is in the report); --first-tries bounds the repeats
            for _ in range(args.first_tries):
                if node.explore_once(args.views, args.method, args.timeout) > 0:
                    break
            while time.time() < args.until:
                node.explore_once(args.views, args.method, args.timeout)
            node.final_diagnostics()
        except TimeoutError as exc:
            node.log_event(event="error", message=str(exc))
            return 1
        return 0

    return run_session(node, explore, on_interrupt=node.cancel)


if __name__ == "__main__":
    raise SystemExit(main())
