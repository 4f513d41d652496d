"""A City-CNN over ROS: /nbv/plan through the servers (the gain server runs the registry's
planner) gives the views of the core planner, with weights from $NBV_WEIGHTS_DIR."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

import test_ros_planning as planning_tests  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import PlanNextBestView  # noqa: E402
from test_ros_planning import GEOMETRY, call, random_grid  # noqa: E402

from nbv_prob_cnn.ros.conversions import grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

ros = planning_tests.ros_fixture(160, 10)  # the same fixture, on this module's domains 160..169


@pytest.fixture
def weights_dir(tmp_path, monkeypatch):
    """Untrained (seeded) weights of the three City-CNNs for 3du, in a folder the nodes are pointed to."""
    import torch

    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.completion.inference import clear_model_cache, save_weights
    from nbv_prob_cnn.planners.city_cnn import CITY_METHODS, build_network

    torch.manual_seed(0)
    folder = tmp_path / "weights"
    for method in CITY_METHODS:
        save_weights(build_network(method, dataset_spec("3du"), 2), folder / f"3du_{method}.pt", "3du", name=method)
    monkeypatch.setenv("NBV_WEIGHTS_DIR", str(folder))
    clear_model_cache()
    yield folder
    clear_model_cache()


def test_city_cnn_plans_through_the_servers(weights_dir, ros):
    from nbv_prob_cnn.planners import PlanningContext, make_planner
    from nbv_prob_cnn.planners.city_cnn import CITY_METHODS

    node, graph, context = ros
    graph.start_node("gain_server", "gain_server", {"dataset": "3du", "backend": "opencl"})
    graph.start_node("nbv_planner", "nbv_planner", {"dataset": "3du", "method": "prob_ig"})
    state = random_grid(5)
    node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS).publish(grid_to_msg(state, GEOMETRY))
    first = PlanNextBestView.Request(top_k=5, method="d_city_cnn")
    # the first plan loads torch and the network in gain_server: under a heavy load (the hunt's load 10)
    # it took over a minute, so it gets 180 s; until the grid arrives the planner answers "no grid"
    deadline = time.monotonic() + 30.0
    while "no grid" in (reply := call(node, context, PlanNextBestView, "/nbv/plan", first, 180.0)).message:
        assert time.monotonic() < deadline, reply.message
        time.sleep(0.5)
    assert reply.success, reply.message
    for method in CITY_METHODS:  # each City-CNN through the same servers
        reply = call(node, context, PlanNextBestView, "/nbv/plan", PlanNextBestView.Request(top_k=5, method=method))
        assert reply.success, (method, reply.message)
        core = make_planner(method).rank(state, PlanningContext.for_dataset("3du", backend="opencl"), 5)
        assert len(reply.ranked) == len(core) == 5, method
        np.testing.assert_allclose([v.gain for v in reply.ranked], [c.gain for c in core], rtol=1e-5, err_msg=method)
        for view, choice in zip(reply.ranked, core, strict=True):
            p = view.pose.pose.position
            np.testing.assert_allclose([p.x, p.y, p.z], GEOMETRY.cell_centre(choice.cell), atol=1e-6, err_msg=method)
        assert reply.time_cnn_s > 0 or reply.time_views_s > 0, method

    # six plans at once (a client resending while a plan runs): the planner serves them one after
    # another, so the gain server's answers always find a free thread of its executor (4 threads:
    # six plans in parallel held them all, and no rank_views answer was taken until a plan timed
    # out, 60 s later; hunt D round 7)
    import rclpy

    from nbv_prob_cnn.ros.graph import call_with_resend

    client = node.create_client(PlanNextBestView, "/nbv/plan")
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        quick = PlanNextBestView.Request(top_k=1, method="prob_ig")
        assert call_with_resend(client, quick, 120.0, executor=executor).success  # matched: no request lost
        futures = [client.call_async(quick) for _ in range(6)]
        deadline = time.monotonic() + 240.0
        while not all(f.done() for f in futures) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.remove_node(node)
    replies = [f.result() for f in futures if f.done()]
    assert len(replies) == 6 and all(r.success for r in replies), [r.message for r in replies]
