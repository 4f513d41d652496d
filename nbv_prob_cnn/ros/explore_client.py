"""A command-line client of the Explore action: sends a goal, prints progress per view, and
writes the per-view CSV, a PNG of the explored grid and ``graph.json`` (every node's topics and
services at the end) (run by the launch scripts as its own
process: ``python -m nbv_prob_cnn.ros.explore_client --views 10 --out DIR``). Ctrl-C (SIGINT)
or SIGTERM cancels the running exploration and waits for its CANCELED result before exiting.

In a simulated world (``--world-dataset``/``--world-seed``: the graph's grid lies on its ground
truth) each view's surface coverage is measured on the view's own grid (the integrator's grid the
planner waited for after the move: the one with the unknown fraction of the feedback; a view's
line waits for it, :class:`~nbv_prob_cnn.exploration.run_coverage.ViewsAwaitingGrids`), printed and
kept in ``views.csv``; without a world (a real robot) that column is empty."""

from __future__ import annotations

import argparse
import csv
import json
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nbv_prob_cnn_msgs.action import Explore
from nbv_prob_cnn_msgs.msg import VoxelGrid
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from nbv_prob_cnn.basics.grid import unknown_fraction_all
from nbv_prob_cnn.exploration.run_coverage import RunCoverage, ViewsAwaitingGrids
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.action_client import LockedActionClient
from nbv_prob_cnn.ros.conversions import msg_to_grid, pose_to_arrays
from nbv_prob_cnn.ros.graph import send_goal_with_resend
from nbv_prob_cnn.ros.qos import GRID_QOS
from nbv_prob_cnn.ros.readiness import TOPIC_DIAGNOSTICS, planner_readiness
from nbv_prob_cnn.ros.runtime import SPIN_PERIOD_S
from nbv_prob_cnn.ros.stream_node import STREAMS_SUFFIX

#: Terminal states of a goal, by ``action_msgs/GoalStatus`` value.
STATUS_NAMES = {GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_CANCELED: "canceled",
                GoalStatus.STATUS_ABORTED: "aborted"}  # fmt: skip


class ExploreClient:
    """Runs one exploration through ``/nbv/explore`` and keeps the latest ``/nbv/grid``."""

    def __init__(self) -> None:
        self.node = rclpy.create_node("explore_client")
        self._action = LockedActionClient(self.node, Explore, names.EXPLORE)
        self._grid: VoxelGrid | None = None
        self._grid_lock = threading.Lock()
        self.node.create_subscription(VoxelGrid, names.GRID, self._on_grid, GRID_QOS)
        self.planner_state: tuple[bytes, str] | None = None  # (level, message) on /diagnostics
        self.node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self._on_diagnostics, 10)
        self.feedback: list[tuple[float, Explore.Feedback]] = []
        self.status = ""  # of the last exploration: succeeded, canceled or aborted
        self.stop_requested = threading.Event()  # set by SIGINT / SIGTERM (see main)
        self.coverage: RunCoverage | None = None  # the world's, when known: set before explore
        self.surface_coverage: dict[int, float] = {}  # view_index -> coverage, of the views taken
        self._awaiting: ViewsAwaitingGrids[tuple[Explore.Feedback, float]] | None = None
        self._on_feedback = None
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self.node)

    def _spin_until(self, future, timeout_s: float, stoppable: bool = True) -> None:
        """Spin until ``future`` is done or ``timeout_s`` passes, at most :data:`SPIN_PERIOD_S`
        per wait (rclpy's signal handler is off: the context must stay up to send a cancel).

        Raises:
            KeyboardInterrupt: ``stop_requested`` was set (only when ``stoppable``).
        """
        self._spin_while_not(future.done, timeout_s, stoppable)

    def _spin_while_not(self, predicate, timeout_s: float, stoppable: bool = True) -> None:
        """Spin until ``predicate()`` holds or ``timeout_s`` passes (see :meth:`_spin_until`)."""
        deadline = time.monotonic() + timeout_s
        while not predicate() and (remaining := deadline - time.monotonic()) > 0:
            if stoppable and self.stop_requested.is_set():
                raise KeyboardInterrupt
            self._executor.spin_once(timeout_sec=min(SPIN_PERIOD_S, remaining))

    def _on_grid(self, msg: VoxelGrid) -> None:
        with self._grid_lock:
            self._grid = msg
        if self._awaiting is not None and self._awaiting.waiting:  # a view's grid may be this one
            self._awaiting.offer(self._grid_array)

    def _grid_array(self):
        grid = self.latest_grid()
        return None if grid is None else msg_to_grid(grid)

    def latest_grid(self) -> VoxelGrid | None:
        with self._grid_lock:
            return self._grid

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        readiness = planner_readiness(msg)
        if readiness is not None:
            self.planner_state = readiness

    def not_ready(self) -> str:
        """What the graph still lacks before a goal is sent ("" when nothing): the Explore server,
        a first grid, the planner's readiness (``/diagnostics`` OK, :mod:`~nbv_prob_cnn.ros.readiness`:
        e.g. its arm set-up; an ERROR state counts as ready, the exploration then reports it)."""
        if not self._action.server_is_ready():
            return "the Explore action server"
        if self.latest_grid() is None:
            return "a first grid on " + names.GRID
        if self.planner_state is None:
            return "the planner's state on " + TOPIC_DIAGNOSTICS
        level, message = self.planner_state
        return f"the planner ({message})" if level == DiagnosticStatus.WARN else ""

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait for the action server, a first grid and a planner that can plan at once (see
        :meth:`not_ready`)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.stop_requested.is_set():
                raise KeyboardInterrupt
            self._executor.spin_once(timeout_sec=SPIN_PERIOD_S)
            if not self.not_ready():
                return True
        return False

    def explore(self, goal: Explore.Goal, timeout_s: float, on_feedback=None) -> Explore.Result:
        """Send ``goal`` and spin until the result arrives.

        Raises:
            RuntimeError: goal rejected; TimeoutError: no result in time.
        """
        start = time.monotonic()
        self._on_feedback = on_feedback
        if self.coverage is not None:
            self._awaiting = ViewsAwaitingGrids(self.coverage, self._release_feedback)

        def feedback_cb(message) -> None:
            fb, elapsed = message.feedback, time.monotonic() - start
            self.feedback.append((elapsed, fb))
            if self._awaiting is None:
                self._release_feedback((fb, elapsed), None)
                return
            view = (fb.unknown_fraction, pose_to_arrays(fb.pose.pose)[0]) if fb.executed else None
            self._awaiting.add((fb, elapsed), view, self._grid_array)

        try:  # the same goal sent again while no answer comes (a first request can be lost, see graph)
            handle = send_goal_with_resend(
                self._action, goal, 30.0, feedback_callback=feedback_cb, wait=self._spin_while_not, resend_s=5.0
            )
        except TimeoutError as exc:
            raise RuntimeError(f"the Explore goal got no answer: {exc}") from exc
        if not handle.accepted:
            raise RuntimeError(
                "the Explore goal was rejected (max_views < 1, a non-finite threshold, or another exploration "
                "is running: see nbv_planner's log)"
            )
        self._goal_handle = handle
        self._result = result = handle.get_result_async()
        self._spin_until(result, timeout_s)
        if not result.done():
            raise TimeoutError(f"no Explore result within {timeout_s:.0f} s")
        # let the last grid arrive
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            self._executor.spin_once(timeout_sec=0.1)
        if self._awaiting is not None:
            self._awaiting.give_up()
            if self._awaiting.off:
                print(f"[explore] surface coverage off: {self._awaiting.off}", file=sys.stderr, flush=True)
            if self._awaiting.missed:
                print(f"[explore] surface coverage: the grids of {self._awaiting.missed} views did not reach the "
                      "client (left empty)", file=sys.stderr, flush=True)  # fmt: skip
        self.status = STATUS_NAMES.get(result.result().status, str(result.result().status))
        return result.result().result

    def _release_feedback(self, item: tuple[Explore.Feedback, float], coverage: float | None) -> None:
        """A feedback whose view's coverage is known (or none is measured): kept, then shown."""
        fb, elapsed = item
        if coverage is not None:
            self.surface_coverage[fb.view_index] = coverage
        if self._on_feedback:
            self._on_feedback(fb, elapsed)

    def cancel(self, timeout_s: float = 5.0) -> str:
        """Cancel the running exploration and wait for its result; returns its status name
        ("" when no goal was sent or no result came within ``timeout_s``)."""
        handle = getattr(self, "_goal_handle", None)
        if handle is None:
            return ""
        self._spin_until(handle.cancel_goal_async(), timeout_s, stoppable=False)
        result = self._result
        self._spin_until(result, timeout_s, stoppable=False)
        if not result.done():
            return ""
        self.status = STATUS_NAMES.get(result.result().status, str(result.result().status))
        return self.status

    def graph_report(self) -> dict[str, dict[str, list[list[str]]]]:
        """Every node of the graph with the topics it publishes and subscribes and the services it
        serves and calls (``[name, type]`` pairs; actions appear as their ``_action`` topics and
        services): what the robot side and our nodes exchange."""
        node = self.node
        report = {}
        for name, namespace in node.get_node_names_and_namespaces():
            if name == node.get_name():
                continue
            full = f"{namespace.rstrip('/')}/{name}"
            try:
                report[full] = {
                    kind: sorted([topic, ",".join(types)] for topic, types in query(name, namespace))
                    for kind, query in (
                        ("publishes", node.get_publisher_names_and_types_by_node),
                        ("subscribes", node.get_subscriber_names_and_types_by_node),
                        ("serves", node.get_service_names_and_types_by_node),
                        ("calls", node.get_client_names_and_types_by_node),
                    )
                }
            except Exception as exc:  # a node that left meanwhile (rclpy raises NodeNameNonExistentError)
                report[full] = {"error": [[str(exc), ""]]}
        return merge_stream_nodes(report)

    def destroy(self) -> None:
        self._executor.shutdown()
        self.node.destroy_node()


def merge_stream_nodes(report: dict[str, dict[str, list[list[str]]]]) -> dict[str, dict[str, list[list[str]]]]:
    """``report`` with each node's side node (``<node>_streams``, :mod:`~nbv_prob_cnn.ros.stream_node`:
    its joint_states and /tf subscriptions) listed under the node itself."""
    merged = {name: dict(entry) for name, entry in report.items()}
    for name in [n for n in merged if n.endswith(STREAMS_SUFFIX)]:
        owner = name[: -len(STREAMS_SUFFIX)]
        if owner not in merged or "error" in merged[owner] or "error" in merged[name]:
            continue
        side = merged.pop(name)
        for kind, pairs in side.items():
            merged[owner][kind] = [list(p) for p in sorted({tuple(p) for p in merged[owner].get(kind, []) + pairs})]
    return merged


def write_outputs(client: ExploreClient, result: Explore.Result, out_dir: Path, title: str) -> list[Path]:
    """Per-view CSV and a PNG of the last grid with the chosen views; when the planner drove the
    arm (feedback with joint goals) the CSV adds the joint travel and goal of each view and the
    PNG the arm at each view (default robot description). ``surface_coverage`` is the client's
    per-view coverage (empty where none was measured: no world known). Moves that failed
    (``executed`` false) are not views: they are counted in the result's ``failed_executions``.
    Views count from 1, as the console does."""
    from nbv_prob_cnn.viz.exploration import plot_views

    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out_dir / "views.csv"
    taken = [(elapsed, fb) for elapsed, fb in client.feedback if fb.executed]
    joint_names = next((list(fb.joint_goal.name) for _, fb in taken if fb.joint_goal.name), [])
    with open(csv_path, "w", newline="") as handle:
        writer = csv.writer(handle)
        header = ["view", "elapsed_s", "gain", "unknown_fraction", "surface_coverage", "x_m", "y_m", "z_m"]
        header += ["qx", "qy", "qz", "qw"]
        header.append("fallback")  # 1: the planner found no feasible ranked view and took one near the camera
        writer.writerow(header + (["joint_travel", *joint_names] if joint_names else []))
        for elapsed, fb in taken:
            position, quat = pose_to_arrays(fb.pose.pose)
            arm = [f"{fb.joint_travel:.6f}", *(f"{v:.6f}" for v in fb.joint_goal.position)] if joint_names else []
            surface = client.surface_coverage.get(fb.view_index)
            writer.writerow(
                [fb.view_index + 1, f"{elapsed:.3f}", f"{fb.gain:.6g}", f"{fb.unknown_fraction:.6f}",
                 "" if surface is None else f"{surface:.6f}", *(f"{v:.5f}" for v in position),
                 *(f"{v:.6f}" for v in quat), int(fb.fallback), *arm]
            )  # fmt: skip
    written = [csv_path]
    grid = client.latest_grid()
    if grid is not None:
        state, geometry = msg_to_grid(grid)
        poses = [pose_to_arrays(p.pose) for p in result.poses]
        cells = np.array([geometry.to_index(p) for p, _ in poses]).reshape(-1, geometry.dims)
        quats = np.array([q for _, q in poses]).reshape(-1, 4)
        curve = ([fb.view_index + 1 for _, fb in taken], [fb.unknown_fraction for _, fb in taken])  # 1 = first view
        png = out_dir / "explored.png"
        arms = arm_polylines([fb.joint_goal for _, fb in taken], geometry) if joint_names else None
        plot_views(
            state,
            cells,
            quats,
            png,
            f"{title} (unknown {unknown_fraction_all(state):.3f})",
            curve=curve,
            arms=arms,
            geometry=geometry,
        )
        np.savez_compressed(
            out_dir / "grid.npz", grid=state, origin=np.array(geometry.origin), resolution=geometry.resolution
        )
        written += [png, out_dir / "grid.npz"]
    return written


def arm_polylines(joint_goals: list, geometry) -> list[np.ndarray] | None:
    """The default robot drawn at each joint goal, in continuous index coordinates of the grid."""
    from nbv_prob_cnn.arm.robot import RobotModel
    from nbv_prob_cnn.arm.views import arm_polyline

    robot = RobotModel()
    try:
        return [
            geometry.to_index(arm_polyline(robot, robot.joint_state_configuration(goal.name, goal.position)))
            for goal in joint_goals
        ]
    except ValueError:  # another robot than the default Panda: the picture shows the views only
        return None


def main(argv: list[str] | None = None) -> int:
    """Run one exploration; exit 0 when it succeeded with at least one view, 130 on Ctrl-C."""
    parser = argparse.ArgumentParser(description="Send an Explore goal to /nbv/explore and record the run.")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--method", default="")
    parser.add_argument("--stop-unknown", type=float, default=0.0)
    parser.add_argument("--out", default="out/explore")
    parser.add_argument("--title", default="exploration")
    parser.add_argument(
        "--world-dataset", choices=["3du", "3dt"],
        help="the simulated world the graph explores (with --world-seed): each view's surface coverage is measured",
    )  # fmt: skip
    parser.add_argument("--world-seed", type=int, help="its seed")
    parser.add_argument("--timeout", type=float, default=1800.0)
    parser.add_argument(
        "--ready-timeout",
        type=float,
        default=300.0,
        help="seconds to wait for the Explore server, a first grid and the planner's set-up",
    )
    args = parser.parse_args(argv)
    if (args.world_dataset is None) != (args.world_seed is None):
        parser.error("--world-dataset and --world-seed go together")
    if args.world_seed is not None and args.world_seed < 0:
        parser.error(f"--world-seed: expected a seed >= 0, got {args.world_seed}")
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    client = ExploreClient()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: client.stop_requested.set())
    try:
        print("[explore] waiting for the graph (the Explore server, a first grid, the planner's set-up)...", flush=True)
        waited = time.monotonic()
        if not client.wait_ready(args.ready_timeout):
            print(f"[explore] graph not ready after {args.ready_timeout:.0f} s: still waiting for {client.not_ready()}",
                  file=sys.stderr, flush=True)  # fmt: skip
            return 1
        print(f"[explore] graph ready after {time.monotonic() - waited:.1f} s", flush=True)
        if args.world_dataset is not None:  # the camera's world, cached by sim_camera by now
            from nbv_prob_cnn.worlds import load_or_generate

            client.coverage = RunCoverage.of_world(load_or_generate(args.world_dataset, args.world_seed))
        goal = Explore.Goal(method=args.method, max_views=args.views, stop_unknown_fraction=args.stop_unknown)

        def progress(fb, elapsed):
            if not fb.executed:
                print(f"[explore] view {fb.view_index + 1}/{args.views}: move failed, trying the next ranked view "
                      f"({fb.execution_error})", flush=True)  # fmt: skip
                return
            rate = (fb.view_index + 1) / elapsed if elapsed > 0 else 0.0
            eta = (args.views - fb.view_index - 1) / rate if rate > 0 else float("nan")
            travel = f", joint travel {fb.joint_travel:.3f} rad" if fb.joint_goal.name else ""
            surface = client.surface_coverage.get(fb.view_index)
            covered = "" if surface is None else f", surface coverage {surface:.4f}"
            print(
                f"[explore] view {fb.view_index + 1}/{args.views}: gain {fb.gain:.4f}, unknown "
                f"{fb.unknown_fraction:.4f}{covered}{travel}, {elapsed:.1f} s elapsed, {rate:.2f} views/s, "
                f"ETA {eta:.0f} s",
                flush=True,
            )

        started = time.monotonic()
        result = client.explore(goal, args.timeout, progress)
        written = write_outputs(client, result, Path(args.out), args.title)
        graph = Path(args.out) / "graph.json"
        graph.write_text(json.dumps(client.graph_report(), indent=1, sort_keys=True))
        written.append(graph)
        print(
            f"[explore] done: {result.views} views in {time.monotonic() - started:.1f} s, final unknown fraction "
            f"{result.final_unknown_fraction:.4f}, {result.failed_executions} failed moves, {result.fallbacks} "
            f"near-camera fallbacks, {client.status}: "
            f"{result.reason_stopped}; wrote " + ", ".join(str(p) for p in written),
            flush=True,
        )
        return 0 if client.status == "succeeded" and result.views > 0 else 1
    except KeyboardInterrupt:
        if getattr(client, "_goal_handle", None) is None:
            print("[explore] interrupted before a goal was sent", flush=True)
            return 130
        print("[explore] interrupted: cancelling the exploration", flush=True)
        status = client.cancel()
        print(f"[explore] exploration {status or 'not confirmed ended'}", flush=True)
        return 130
    except (RuntimeError, TimeoutError) as exc:
        print(f"[explore] {exc}", file=sys.stderr, flush=True)
        return 1
    finally:
        client.destroy()
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())
