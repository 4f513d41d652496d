"""The second client of ``nbv study soak``: until a set time, sends a random mix of valid and invalid
requests (:class:`~studies.soak_report.RequestMix`) to every service of the
graph and an invalid goal now and then to the Explore action; each request and its outcome
(success, error answered, or no answer in time) is one JSON line of its event log. Run by
:mod:`studies.soak` as its own process:
``nbv study soak_requester --until EPOCH --events FILE --save-dir DIR``."""

from __future__ import annotations

import json
import random
import threading
import time
from pathlib import Path

import rclpy
from geometry_msgs.msg import PoseStamped
from nbv_prob_cnn_msgs.action import Explore
from nbv_prob_cnn_msgs.msg import VoxelGrid
from nbv_prob_cnn_msgs.srv import CompleteGrid, EvaluateViews, MoveCamera, PlanNextBestView, RankViews, SaveGrid
from std_srvs.srv import Trigger

from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.qos import GRID_QOS
from studies._soak_client import SoakClient, client_parser, run_session
from studies.soak_report import KINDS, RequestMix, RequestSpec

#: A service not seen this long is recorded as unavailable instead of called [s].
UNAVAILABLE_AFTER_S = 2.0
SERVICE_TYPES = {
    "plan": PlanNextBestView,
    "complete": CompleteGrid,
    "rank_views": RankViews,
    "evaluate_views": EvaluateViews,
    "move_to": MoveCamera,
    "integrator_reset": Trigger,
    "integrator_save": SaveGrid,
    "integrator_diagnostics": Trigger,
}


def pose_msg(values: list[float]) -> PoseStamped:
    """``[x, y, z, qx, qy, qz, qw]`` in the grid frame (empty frame_id)."""
    pose = PoseStamped()
    p, q = pose.pose.position, pose.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = (float(v) for v in values)
    return pose


class SoakRequester(SoakClient):
    """Sends the requests of a :class:`RequestMix` one at a time and logs their outcomes."""

    def __init__(self, events: Path, timeout_s: float) -> None:
        super().__init__("soak_requester", events)
        self.timeout_s = timeout_s
        self.clients_ = {kind: self.create_client(srv, KINDS[kind]) for kind, srv in SERVICE_TYPES.items()}
        self._grid: VoxelGrid | None = None
        self._lock = threading.Lock()
        self.create_subscription(VoxelGrid, names.GRID, self._on_grid, GRID_QOS)

    def _on_grid(self, msg: VoxelGrid) -> None:
        with self._lock:
            self._grid = msg

    def wait_ready(self, timeout_s: float) -> list[str]:
        """Wait for every service, the action server and a first grid; returns what is missing."""
        deadline = time.monotonic() + timeout_s
        missing = []
        for kind, client in self.clients_.items():
            if not client.wait_for_service(timeout_sec=max(deadline - time.monotonic(), 0.1)):
                missing.append(KINDS[kind])
        if not self._action.wait_for_server(timeout_sec=max(deadline - time.monotonic(), 0.1)):
            missing.append(names.EXPLORE)
        while self._grid is None and time.monotonic() < deadline:
            self.executor_.spin_once(timeout_sec=0.1)
        if self._grid is None:
            missing.append(names.GRID)
        # let DDS finish matching the reply readers (a request sent right away can be lost)
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            self.executor_.spin_once(timeout_sec=0.1)
        return missing

    def _grid_field(self, which: str) -> VoxelGrid:
        with self._lock:
            latest = self._grid
        if which == "empty" or latest is None:
            return VoxelGrid()
        if which == "truncated":
            cut = VoxelGrid(header=latest.header, origin=latest.origin, resolution=latest.resolution,
                            size_x=latest.size_x, size_y=latest.size_y, size_z=latest.size_z)  # fmt: skip
            cut.data = latest.data[: len(latest.data) // 2]
            return cut
        return latest

    def build(self, spec: RequestSpec):
        f = spec.fields
        kind = spec.kind
        if kind == "plan":
            return PlanNextBestView.Request(method=f.get("method", ""), max_origins=f.get("max_origins", 0),
                                            top_k=f.get("top_k", 0))  # fmt: skip
        if kind == "complete":
            return CompleteGrid.Request(grid=self._grid_field(f["grid"]), dataset=f.get("dataset", ""))
        if kind == "rank_views":
            return RankViews.Request(grid=self._grid_field(f["grid"]), method=f.get("method", ""),
                                     top_k=f.get("top_k", 0), max_origins=f.get("max_origins", 0))  # fmt: skip
        if kind == "evaluate_views":
            return EvaluateViews.Request(poses=[pose_msg(p) for p in f["poses"]], method=f.get("method", ""))
        if kind == "move_to":
            return MoveCamera.Request(target=pose_msg(f["pose"]))
        if kind == "integrator_save":
            return SaveGrid.Request(path=f["path"])
        return Trigger.Request()

    def send(self, spec: RequestSpec) -> None:
        start = time.monotonic()
        event = {"event": "request", "kind": spec.kind, "valid": spec.valid, "variant": spec.variant}
        if spec.kind == "explore_goal":
            goal = Explore.Goal(max_views=spec.fields.get("max_views", 0),
                                stop_unknown_fraction=spec.fields.get("stop_unknown_fraction", 0.0))  # fmt: skip
            future = self._action.send_goal_async(goal)
            self.executor_.spin_until_future_complete(future, timeout_sec=self.timeout_s)
            if not future.done():
                event.update(outcome="timeout")
            elif future.result() is None:
                event.update(outcome="unavailable", message="no answer (the server left)")
            else:
                handle = future.result()
                event.update(outcome="success" if handle.accepted else "error",
                             message="accepted" if handle.accepted else "rejected")  # fmt: skip
                if handle.accepted:  # not ours to run: the explorer's goal must not be disturbed
                    cancel = handle.cancel_goal_async()
                    self.executor_.spin_until_future_complete(cancel, timeout_sec=10.0)
        elif not self.clients_[spec.kind].wait_for_service(timeout_sec=UNAVAILABLE_AFTER_S):
            event.update(outcome="unavailable", message=f"{KINDS[spec.kind]} not available")
        else:
            client = self.clients_[spec.kind]
            future = client.call_async(self.build(spec))
            self.executor_.spin_until_future_complete(future, timeout_sec=self.timeout_s)
            if not future.done():
                client.remove_pending_request(future)
                event.update(outcome="timeout")
            else:
                reply = future.result()
                event.update(outcome="success" if reply.success else "error", message=reply.message[:300])
                if spec.kind == "integrator_diagnostics":
                    event["report"] = json.loads(reply.message)
                    event["message"] = ""
        event["seconds"] = round(time.monotonic() - start, 4)
        self.log_event(**event)

    def pause(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (remaining := end - time.monotonic()) > 0:
            self.executor_.spin_once(timeout_sec=min(remaining, 0.1))


def main(argv: list[str] | None = None) -> int:
    parser = client_parser("Send random valid and invalid requests until --until.", "stop sending then (epoch s)")
    parser.add_argument("--save-dir", required=True, help="directory of the valid integrator/save requests")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--grid-centre", type=float, nargs=3, default=[0.37, 0.37, 0.37], metavar=("X", "Y", "Z"))
    parser.add_argument("--period", type=float, default=1.0, help="mean pause between requests [s]")
    parser.add_argument("--timeout", type=float, default=60.0, help="longest wait for one answer [s]")
    parser.add_argument("--ready-timeout", type=float, default=120.0)
    args = parser.parse_args(argv)
    rclpy.init()
    node = SoakRequester(args.events, args.timeout)
    mix = RequestMix(args.seed, tuple(args.grid_centre), args.save_dir)
    pauses = random.Random(args.seed + 1)

    def send_requests() -> int:
        missing = node.wait_ready(args.ready_timeout)
        if missing:
            node.log_event(event="error", message=f"not available within {args.ready_timeout:g} s: {missing}")
            return 1
        node.log_event(event="ready")
        for spec in mix.first_round():
            node.send(spec)
        while time.time() < args.until:
            node.send(mix.next())
            node.pause(min(pauses.expovariate(1.0 / args.period), 5 * args.period))
        return 0

    return run_session(node, send_requests)


if __name__ == "__main__":
    raise SystemExit(main())
