"""Transport overhead of the node split: ``/nbv/plan`` round trips through the completion and
gain servers against the same computation in one process (``nbv bench --suite ros``).

The grid is a half-explored world of ``dataset`` or, with ``shape``, the tabletop-like grid of that
size of ``nbv bench --suite scale`` (:func:`~nbv_prob_cnn.bench.scale.scale_state`, 3DT cells and
weights): a 256 × 256 × 192 grid is 12.6 MB as a ``VoxelGrid`` and 50 MB as a ``ProbabilityGrid``.
The grid reaches the planner as the integrator's ``/nbv/grid`` would."""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from nbv_prob_cnn.basics.camera import dataset_defaults
from nbv_prob_cnn.bench.planning import half_explored
from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner, PlanningContext
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.graph import NodeGraph, ros_environment, wait_for


def ros_latency_benchmark(
    dataset: str = "3du",
    method: str = "cnn_prob",
    seed: int = 1000,
    repeats: int = 5,
    shape: tuple[int, int, int] | None = None,
) -> str:
    """Median ``/nbv/plan`` round trip vs in-process planning on a ~50 % explored grid, measured
    alternately; a markdown table. ``shape``: the scale suite's grid of that size (dataset 3DT)."""
    import rclpy
    from nbv_prob_cnn_msgs.msg import VoxelGrid
    from nbv_prob_cnn_msgs.srv import PlanNextBestView

    from nbv_prob_cnn.ros.conversions import grid_to_msg
    from nbv_prob_cnn.ros.qos import GRID_QOS
    from nbv_prob_cnn.worlds import load_or_generate

    if shape is None:
        world = load_or_generate(dataset, seed)
        defaults = dataset_defaults(dataset)
        state = half_explored(world, PlanningContext(defaults, rng=np.random.default_rng(seed)))
        geometry = world.geometry
    else:
        from nbv_prob_cnn.basics.geometry import GridGeometry
        from nbv_prob_cnn.bench.scale import scale_state

        dataset = "3dt"
        defaults = dataset_defaults(dataset)
        state = scale_state(shape, seed)
        geometry = GridGeometry((0.0, 0.0, 0.0), defaults.resolution_m, state.shape)

    planner = GainPlanner(GAIN_METHODS[method])
    context = PlanningContext(defaults, rng=np.random.default_rng(0), backend="opencl")
    planner.rank(state, context, 20)  # warm-up: model load, kernel build

    def in_process() -> float:
        start = time.perf_counter()
        planner.rank(state, context, 20)  # the planner node asks the servers for its 20 markers too
        return time.perf_counter() - start

    env = ros_environment()
    os.environ.update(env)
    with NodeGraph(env) as graph:
        graph.start_node("completion_server", "completion_server", {"dataset": dataset})
        graph.start_node("gain_server", "gain_server", {"dataset": dataset, "backend": "opencl"})
        graph.start_node(
            "nbv_planner", "nbv_planner", {"dataset": dataset, "method": method, "service_timeout_s": 600.0}
        )
        rclpy.init()
        node = rclpy.create_node("latency_benchmark")
        publisher = node.create_publisher(VoxelGrid, names.GRID, GRID_QOS)
        publisher.publish(grid_to_msg(state, geometry))
        client = node.create_client(PlanNextBestView, names.PLAN)

        def round_trip() -> tuple[float, bool]:
            start = time.perf_counter()
            future = client.call_async(PlanNextBestView.Request(top_k=1))
            rclpy.spin_until_future_complete(node, future, timeout_sec=600)
            return time.perf_counter() - start, bool(future.done() and future.result().success)

        try:
            if not client.wait_for_service(timeout_sec=60) or not wait_for(lambda: round_trip()[1], 600, 0.5):
                raise RuntimeError("the planning graph did not answer /nbv/plan")
            # alternate the two so that background load affects both alike
            local, remote = [], []
            for _ in range(repeats):
                local.append(in_process())
                remote.append(round_trip()[0])
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    t_local, t_remote = statistics.median(local), statistics.median(remote)
    return "\n".join(
        [
            "| grid | method | in-process planning (s) | /nbv/plan round trip (s) | transport overhead |",
            "|---|---|---|---|---|",
            (
                f"| {dataset.upper()} {'×'.join(map(str, state.shape))} | {method} | {t_local:.3f} | {t_remote:.3f} | "
                f"{100 * (t_remote - t_local) / t_local:+.0f} % |"
            ),
        ]
    )
