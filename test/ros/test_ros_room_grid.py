"""Issue 35, "through the nodes": a 256 × 256 × 192 grid (12.6 M cells: a 12.6 MB ``VoxelGrid``, a
50 MB ``ProbabilityGrid``) published as the integrator's ``/nbv/grid/compressed`` and planned on by
``nbv_planner`` through ``completion_server`` and ``gain_server``, ``cnn_prob`` in a workspace box:
the same ranking as the in-process planner on the same grid; then by a planner with the CNN window
(``cnn_window``), whose completion request carries the window alone: the same ranking as the
in-process planner with that window, and the same window with an origin budget (drawn by gain_server)."""

from __future__ import annotations

import os
import re
import signal
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from nbv_prob_cnn_msgs.msg import CompressedVoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import CompleteGrid, PlanNextBestView, RankViews  # noqa: E402
from test_ros_planning import ros_fixture  # noqa: E402

from nbv_prob_cnn.basics.camera import dataset_defaults  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.planners import GainPlanner, PlanningContext  # noqa: E402
from nbv_prob_cnn.planners.methods import GAIN_METHODS  # noqa: E402
from nbv_prob_cnn.planners.requests import origin_filter  # noqa: E402
from nbv_prob_cnn.ros.conversions import compress_grid_msg, grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import call_with_resend, wait_for  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

pytestmark = pytest.mark.slow  # a ROS graph and a room-sized CNN pass

ros = ros_fixture(221, 12)  # test_ros_planning's domains (each test reserves a free one)

SHAPE = (256, 256, 192)
GEOMETRY = GridGeometry((0.0, 0.0, 0.0), dataset_defaults("3dt").resolution_m, SHAPE)
#: The camera workspace of the plan: a 0.25 m box above the middle of the table [m, grid frame].
BOX_MIN, BOX_MAX = np.array([1.36, 1.36, 0.3]), np.array([1.61, 1.61, 0.55])


def room_grid(seed: int = 7) -> np.ndarray:
    """A tabletop-like 256 × 256 × 192 state: a known table top (empty above, occupied at z < 8),
    random boxes on it, the far half of the room and a shell around the boxes unknown."""
    rng = np.random.default_rng(seed)
    state = np.zeros(SHAPE, dtype=np.int8)
    state[:, :, :8] = 1
    for corner in rng.integers((16, 16, 8), (224, 224, 40), size=(40, 3)):
        lo, size = corner, rng.integers(6, 24, size=3)
        state[lo[0] - 3 : lo[0] + size[0] + 3, lo[1] - 3 : lo[1] + size[1] + 3, lo[2] : lo[2] + size[2] + 3] = -1
        state[lo[0] : lo[0] + size[0], lo[1] : lo[1] + size[1], lo[2] : lo[2] + size[2]] = 1
    state[160:, :, 8:] = -1
    return state


def test_a_room_sized_grid_is_planned_on_through_the_servers(ros):
    node, graph, context = ros
    graph.start_node("completion_server", "completion_server", {"dataset": "3dt"})
    graph.start_node("gain_server", "gain_server", {"dataset": "3dt", "backend": "opencl"})
    # the planner reads the compressed topic (a room-sized grid: 12.6 MB raw)
    planner = {"dataset": "3dt", "method": "cnn_prob", "service_timeout_s": 300.0, "grid_transport": "compressed"}
    graph.start_node("nbv_planner", "nbv_planner", planner)
    state = room_grid()
    message = grid_to_msg(state, GEOMETRY)
    assert len(message.data) == 256 * 256 * 192
    packed = compress_grid_msg(message)
    assert len(packed.data) < len(message.data) / 20
    publisher = node.create_publisher(CompressedVoxelGrid, "/nbv/grid/compressed", GRID_QOS)
    publisher.publish(packed)

    request = PlanNextBestView.Request(top_k=5, use_workspace=True)
    request.workspace_min.x, request.workspace_min.y, request.workspace_min.z = (float(v) for v in BOX_MIN)
    request.workspace_max.x, request.workspace_max.y, request.workspace_max.z = (float(v) for v in BOX_MAX)
    # the planner fails a plan at once while a server is not up (completion_server loads torch and
    # warms the network up first: over a minute at load 11), so the test waits for both servers
    for service_type, name in ((CompleteGrid, "/nbv/complete"), (RankViews, "/nbv/rank_views")):
        assert node.create_client(service_type, name).wait_for_service(timeout_sec=300.0), f"{name} did not come up"
    client = node.create_client(PlanNextBestView, "/nbv/plan")
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    reply = _plan(client, request, executor)
    assert reply.success, reply.message
    assert reply.time_cnn_s > 0.0  # the probabilities came from completion_server

    core_context = PlanningContext(dataset_defaults("3dt"), backend="opencl")
    inside = origin_filter(GEOMETRY, True, BOX_MIN, BOX_MAX, 0, np.random.default_rng(0))
    core = GainPlanner(GAIN_METHODS["cnn_prob"]).rank(state, core_context, 5, inside)
    assert len(core) == 5 and len(reply.ranked) == 5
    # the server completes the whole grid, the core by tiles over the rays' reach: equal within 1e-4
    np.testing.assert_allclose([v.gain for v in reply.ranked], [c.gain for c in core], rtol=1e-3)
    best = np.array([getattr(reply.best_pose.pose.position, a) for a in "xyz"])
    np.testing.assert_allclose(best, GEOMETRY.cell_centre(core[0].cell), atol=1e-6)
    assert np.all(best >= BOX_MIN) and np.all(best <= BOX_MAX)

    # the CNN window: the planner sends the workspace's candidates' box grown by 48 cells alone
    first = graph.processes["nbv_planner"]
    os.killpg(first.pid, signal.SIGINT)
    assert first.wait(timeout=60) == 0
    graph.start_node("nbv_planner_window", "nbv_planner", {**planner, "cnn_window": WINDOW})
    log = graph.log_dir / "nbv_planner_window.log"
    # its own "ready", not the service: the stopped planner's /nbv/plan can linger in the graph's cache
    assert wait_for(lambda: log.exists() and "nbv_planner ready" in log.read_text(), 300.0), "no windowed planner"
    client = node.create_client(PlanNextBestView, "/nbv/plan")
    assert client.wait_for_service(timeout_sec=300.0), "the windowed planner did not come up"
    windowed = _plan(client, request, executor)
    assert windowed.success, windowed.message
    window_context = PlanningContext(dataset_defaults("3dt"), backend="opencl", cnn_window=WINDOW)
    core_window = GainPlanner(GAIN_METHODS["cnn_prob"]).rank(state, window_context, 5, inside)
    np.testing.assert_allclose([v.gain for v in windowed.ranked], [c.gain for c in core_window], rtol=1e-3)
    best = np.array([getattr(windowed.best_pose.pose.position, a) for a in "xyz"])
    np.testing.assert_allclose(best, GEOMETRY.cell_centre(core_window[0].cell), atol=1e-6)

    # with an origin budget gain_server draws the origins: the window still holds every candidate of the
    # workspace (the box of a planner-side draw of 5 would be smaller, and its rays would read p0 there)
    budget = PlanNextBestView.Request(top_k=1, use_workspace=True, max_origins=5)
    budget.workspace_min, budget.workspace_max = request.workspace_min, request.workspace_max
    drawn = _plan(client, budget, executor)
    assert drawn.success, drawn.message
    windows = re.findall(r"complete: 3dt (\d+x\d+x\d+) in", (graph.log_dir / "completion_server.log").read_text())
    assert len(windows) == 3 and windows[2] == windows[1] != "256x256x192", windows
    executor.remove_node(node)


#: The CNN window's margin (cells): 3DT's receptive field.
WINDOW = 48


def _plan(client, request, executor) -> PlanNextBestView.Response:
    """The planner's answer once the grid has arrived ("no grid" before)."""
    for _ in range(120):  # "no grid" while the 12.6 MB grid is on its way
        # a plan takes tens of seconds: a copy sent every 10 s (test_ros_planning.call) would queue
        # duplicate plans, so a copy goes only after 150 s without an answer (a lost request)
        reply = call_with_resend(client, request, 600.0, executor=executor, resend_s=150.0)
        if reply.success or "no grid" not in reply.message:
            break
        time.sleep(0.5)
    return reply
