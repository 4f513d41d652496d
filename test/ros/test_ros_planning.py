"""Multi-process tests of the planning side: gain_server, completion_server, nbv_planner, the
colcon build, with a client node in the test process (as a manipulation stack would be)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import EvaluateViews, PlanNextBestView, RankViews  # noqa: E402

from nbv_prob_cnn.basics.camera import dataset_defaults  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.basics.grid import probability_with_constant  # noqa: E402
from nbv_prob_cnn.gain.settings import DEFAULT_SURFACE_BLEND  # noqa: E402
from nbv_prob_cnn.planners import GainPlanner, PlanningContext  # noqa: E402
from nbv_prob_cnn.planners.methods import GAIN_METHODS  # noqa: E402
from nbv_prob_cnn.planners.pose_scoring import EVALUATE_RAYS_ACROSS, INVALID_POSE, VALID, score_poses  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, call_with_resend, wait_for  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

REPO = Path(__file__).resolve().parents[2]
GEOMETRY = GridGeometry((0.1, -0.2, 0.0), 0.0116, (64, 64, 64))
_counter = iter(range(1000))


def ros_fixture(first_domain: int, n_domains: int):
    """A fixture giving each test a fresh domain (``first_domain`` .. ``first_domain + n_domains - 1``),
    an rclpy context and a client node (other test modules reuse it on their own domains)."""

    @pytest.fixture
    def ros(tmp_path, ros_domain):
        env = ros_domain(first_domain + (os.getpid() + next(_counter)) % n_domains)
        context = rclpy.Context()
        rclpy.init(context=context)
        node = rclpy.create_node("test_client", context=context)
        graph = NodeGraph(env, log_dir=tmp_path / "logs")
        yield node, graph, context
        graph.stop()
        node.destroy_node()
        rclpy.shutdown(context=context)

    return ros


ros = ros_fixture(221, 12)


def call(node, context, srv_type, name, request, timeout_s=60.0):
    """An idempotent request on a fresh client, sent again every 10 s until answered
    (:func:`call_with_resend`)."""
    client = node.create_client(srv_type, name)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        return call_with_resend(client, request, timeout_s, executor=executor)
    finally:
        executor.remove_node(node)
        node.destroy_client(client)


def random_grid(seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    state = np.full(GEOMETRY.shape, -1, dtype=np.int8)
    state[8:56, 8:56, 4:40] = rng.choice(np.array([-1, 0, 0, 0, 1], dtype=np.int8), size=(48, 48, 36))
    return state


def pose_msg(position, quat, frame="world") -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in quat)
    return msg


def test_evaluate_views_matches_core_and_survives_bad_requests(ros):
    node, graph, context = ros
    graph.start_node("gain_server", "gain_server", {"dataset": "3du", "backend": "opencl"})
    # before any grid: a clear error, and the node keeps serving
    early = call(
        node,
        context,
        EvaluateViews,
        "/nbv/evaluate_views",
        EvaluateViews.Request(poses=[pose_msg([0, 0, 0], [0, 0, 0, 1])]),
    )
    assert not early.success and "no grid" in early.message

    state = random_grid()
    publisher = node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS)
    publisher.publish(grid_to_msg(state, GEOMETRY))

    rng = np.random.default_rng(7)
    empty = np.argwhere(state == 0)
    cells = empty[rng.choice(empty.shape[0], 200, replace=False)]
    positions = GEOMETRY.cell_centre(cells) + rng.uniform(-0.4, 0.4, (200, 3)) * GEOMETRY.resolution
    quats = rng.normal(size=(200, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    request = EvaluateViews.Request(
        poses=[pose_msg(p, q) for p, q in zip(positions, quats, strict=True)], method="prob_ig"
    )

    answers = []  # the successful replies, latest last

    def answered() -> bool:
        # false while the server answers that it has no grid yet
        reply = call(node, context, EvaluateViews, "/nbv/evaluate_views", request)
        if reply.success:
            answers.append(reply)
            return True
        return False

    assert wait_for(answered, 30.0, 0.5), "the grid never reached gain_server"
    reply = answers[-1]
    context_core = PlanningContext(dataset_defaults("3du"), backend="opencl")
    expected = score_poses(state, probability_with_constant(state, 0.15), GEOMETRY, positions, quats, context_core,
                           rays_across=EVALUATE_RAYS_ACROSS)  # fmt: skip
    assert np.all(np.array(reply.validity) == VALID)
    # steradians (the frustum's own rays): the best pose's ray gains weigh at least 6 % of its 0.79 sr frustum
    assert np.asarray(reply.gains).max() > 0.05
    np.testing.assert_allclose(np.asarray(reply.gains), expected.gains, rtol=1e-6, atol=1e-7)
    # the surface gain on the constant map: every unknown sample counts (1 - beta) + beta P0 times the
    # paper's term, so each pose scores exactly that factor times prob_ig's score
    request.method = "prob_surface"
    surface = call(node, context, EvaluateViews, "/nbv/evaluate_views", request)
    factor = (1 - DEFAULT_SURFACE_BLEND) + DEFAULT_SURFACE_BLEND * 0.15
    assert surface.success
    np.testing.assert_allclose(np.asarray(surface.gains), factor * expected.gains, rtol=1e-5, atol=1e-7)
    request.method = "prob_ig"

    # bad poses are flagged one by one, with reasons; the rest is still scored
    bad = EvaluateViews.Request(
        poses=[
            pose_msg([np.nan, 0.3, 0.2], [0, 0, 0, 1]),
            pose_msg(positions[0], [0, 0, 0, 0]),
            pose_msg(positions[1], quats[1], frame="map"),
            pose_msg([50.0, 0, 0], [0, 0, 0, 1]),
            pose_msg(positions[2], quats[2]),
        ],
        method="prob_ig",  # the node default is cnn_prob (needs the completion server)
    )
    reply = call(node, context, EvaluateViews, "/nbv/evaluate_views", bad)
    assert reply.success
    assert list(reply.validity[:3]) == [INVALID_POSE] * 3 and reply.validity[4] == VALID
    assert "frame" in reply.reasons[2] and "outside" in reply.reasons[3]
    assert reply.gains[4] == pytest.approx(expected.gains[2], rel=1e-6)

    for bad_request, reason in [
        (EvaluateViews.Request(), "no poses"),
        (EvaluateViews.Request(poses=request.poses[:3], method="city_cnn"), "unknown method"),
    ]:
        reply = call(node, context, EvaluateViews, "/nbv/evaluate_views", bad_request)
        assert not reply.success and reason in reply.message

    mismatch = RankViews.Request(grid=grid_to_msg(state, GEOMETRY), top_k=1)
    mismatch.grid.data = mismatch.grid.data[:-5]
    reply = call(node, context, RankViews, "/nbv/rank_views", mismatch)
    assert not reply.success and "data has" in reply.message
    huge = RankViews.Request(top_k=1)
    huge.grid.size_x, huge.grid.size_y, huge.grid.size_z, huge.grid.resolution = 1000, 1000, 68, 0.01
    huge.grid.data = bytes(50_000_000)  # a 50 MB request declaring 68 M cells (the limit: 2^26 = 67.1 M)
    reply = call(node, context, RankViews, "/nbv/rank_views", huge)
    assert not reply.success and "68000000 cells exceed" in reply.message, reply.message

    # still serving, and a restarted server gets the grid again (transient local), no re-publish
    graph.stop()
    graph.start_node("gain_server_2", "gain_server", {"dataset": "3du", "backend": "opencl"})
    assert wait_for(answered, 60.0, 0.5), "a restarted gain_server lost the grid"


def test_planner_plans_through_the_servers(ros):
    node, graph, context = ros
    # image_rerank 0: the surface methods plan on the view search alone (below, prob_surface ranks as prob_ig;
    # with the default 20 each is re-ranked by its image rays and the ranking differs)
    graph.start_node("gain_server", "gain_server", {"dataset": "3du", "backend": "opencl", "image_rerank": 0})
    graph.start_node("nbv_planner", "nbv_planner", {"dataset": "3du", "method": "prob_ig"})
    early = call(node, context, PlanNextBestView, "/nbv/plan", PlanNextBestView.Request())
    assert not early.success and "no grid" in early.message

    state = random_grid(5)
    publisher = node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS)
    publisher.publish(grid_to_msg(state, GEOMETRY))
    request = PlanNextBestView.Request(top_k=5)
    assert wait_for(lambda: call(node, context, PlanNextBestView, "/nbv/plan", request).success, 30.0, 0.5)
    reply = call(node, context, PlanNextBestView, "/nbv/plan", request)
    core = GainPlanner(GAIN_METHODS["prob_ig"]).rank(
        state, PlanningContext(dataset_defaults("3du"), backend="opencl"), 5
    )
    np.testing.assert_allclose([v.gain for v in reply.ranked], [c.gain for c in core], rtol=1e-6)
    best = np.array([reply.best_pose.pose.position.x, reply.best_pose.pose.position.y, reply.best_pose.pose.position.z])
    cell, inside = GEOMETRY.containing_cell(best)
    assert inside and state[tuple(cell)] == 0
    np.testing.assert_allclose(best, GEOMETRY.cell_centre(core[0].cell), atol=1e-6)
    # a surface method through the servers: prob_surface ranks as prob_ig, each gain the blend's factor times it
    surface = call(
        node, context, PlanNextBestView, "/nbv/plan", PlanNextBestView.Request(top_k=5, method="prob_surface")
    )
    factor = (1 - DEFAULT_SURFACE_BLEND) + DEFAULT_SURFACE_BLEND * 0.15
    assert surface.success, surface.message
    np.testing.assert_allclose([v.gain for v in surface.ranked], [factor * c.gain for c in core], rtol=1e-5)

    # a reachable box: every ranked view is inside it
    boxed = PlanNextBestView.Request(top_k=5, use_workspace=True)
    boxed.workspace_min.x, boxed.workspace_min.y, boxed.workspace_min.z = 0.3, 0.0, 0.1
    boxed.workspace_max.x, boxed.workspace_max.y, boxed.workspace_max.z = 0.6, 0.3, 0.4
    reply = call(node, context, PlanNextBestView, "/nbv/plan", boxed)
    assert reply.success and len(reply.ranked) == 5
    for view in reply.ranked:
        p = view.pose.pose.position
        assert 0.3 <= p.x <= 0.6 and 0.0 <= p.y <= 0.3 and 0.1 <= p.z <= 0.4
    bad = call(node, context, PlanNextBestView, "/nbv/plan", PlanNextBestView.Request(method="nope"))
    assert not bad.success and "unknown method" in bad.message
    assert call(node, context, PlanNextBestView, "/nbv/plan", request).success  # still serving

    # the default method changes at run time; a bad value is refused with a reason
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    def set_method(value: str):
        param = Parameter(name="method", value=ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value))
        return call(
            node, context, SetParameters, "/nbv_planner/set_parameters", SetParameters.Request(parameters=[param])
        )

    refused = set_method("nope").results[0]
    assert not refused.successful and "unknown method" in refused.reason
    assert set_method("ig").results[0].successful
    reply = call(node, context, PlanNextBestView, "/nbv/plan", request)
    core = GainPlanner(GAIN_METHODS["ig"]).rank(state, PlanningContext(dataset_defaults("3du"), backend="opencl"), 5)
    np.testing.assert_allclose([v.gain for v in reply.ranked], [c.gain for c in core], rtol=1e-6)

    # a grid the camera saw nothing of: no view, and the message says why (issue 48: it said no more)
    publisher.publish(grid_to_msg(np.full(GEOMETRY.shape, -1, dtype=np.int8), GEOMETRY))
    assert wait_for(lambda: "no empty cell" in call(node, context, PlanNextBestView, "/nbv/plan", request).message,
                    30.0, 0.5)  # fmt: skip
    empty = call(node, context, PlanNextBestView, "/nbv/plan", request)
    assert not empty.success and empty.message.startswith("no view with positive gain: the grid has no empty cell")


def test_colcon_builds_the_package_and_runs_a_node(ros, tmp_path):
    """colcon builds nbv_prob_cnn in a workspace over the underlay that the set-up built, where the interface
    packages (nbv_prob_cnn_msgs among them) are installed by the same CMake files that colcon would run
    (launch_scripts/build_interfaces.sh); building them again here cost about a minute of the suite."""
    node, graph, context = ros
    venv = Path(os.environ.get("VIRTUAL_ENV", REPO / ".venv"))
    env = dict(
        os.environ, AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv), PATH=f"{venv}/bin:{os.environ['PATH']}"
    )
    workspace = tmp_path / "ws"
    build = subprocess.run(
        # the package; nbv_prob_cnn_msgs, control_msgs and tf2_msgs (msg_defs/) come from the underlay the set-up
        # built, as from a sourced ROS install
        [str(venv / "bin" / "colcon"), "build", "--base-paths", str(REPO),
         "--build-base", str(workspace / "build"), "--install-base", str(workspace / "install"),
         "--cmake-args", "-DBUILD_TESTING=OFF", f"-DPython3_EXECUTABLE={venv}/bin/python"],
        cwd=workspace.parent, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    install = workspace / "install"
    executable = install / "nbv_prob_cnn" / "lib" / "nbv_prob_cnn" / "gain_server"
    assert executable.exists()
    assert (
        install / "nbv_prob_cnn" / "lib" / "python3.11" / "site-packages" / "nbv_prob_cnn" / "gain" / "raycast.cl"
    ).exists()
    # run it from the install space with the environment a sourced workspace gives
    sourced = subprocess.run(
        ["bash", "-c", f". {install}/setup.sh && env"], env=env, capture_output=True, text=True, check=True
    ).stdout
    run_env = dict(line.split("=", 1) for line in sourced.splitlines() if "=" in line)
    graph.env = run_env
    proc = graph.start("installed_gain_server", [str(executable), "--ros-args", "-p", "dataset:=3du"])
    state = random_grid(9)
    publisher = node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS)
    publisher.publish(grid_to_msg(state, GEOMETRY))
    request = RankViews.Request(method="prob_ig", top_k=1)
    assert wait_for(lambda: call(node, context, RankViews, "/nbv/rank_views", request).success, 60.0, 0.5)
    reply = call(node, context, RankViews, "/nbv/rank_views", request)
    assert reply.ranked[0].gain > 0
    assert proc.poll() is None
    code = "import nbv_prob_cnn as a, nbv_prob_cnn_msgs as b; print(a.__file__, b.__file__)"
    probe = subprocess.run(
        [str(venv / "bin" / "python"), "-c", code],
        env=run_env, cwd=tmp_path, capture_output=True, text=True, check=True,
    )  # fmt: skip
    ours, interfaces = probe.stdout.split()
    assert ours.startswith(str(install)), ours  # the package comes from the workspace ...
    assert interfaces.startswith(str(venv)), interfaces  # ... over the underlay's interfaces


def test_completion_server_runs_the_network_in_bfloat16_when_asked(ros, bf16):
    """``precision:=bfloat16``: the served map is the in-process bfloat16 map, not the float32 one."""
    from nbv_prob_cnn_msgs.srv import CompleteGrid

    from nbv_prob_cnn.completion import complete
    from nbv_prob_cnn.ros.conversions import msg_to_probability

    node, graph, context = ros
    graph.start_node("completion_server", "completion_server", {"dataset": "3du", "precision": "bfloat16"})
    state = random_grid(7)
    reply = call(node, context, CompleteGrid, "/nbv/complete",
                 CompleteGrid.Request(grid=grid_to_msg(state, GEOMETRY), dataset="3du"), 120.0)  # fmt: skip
    assert reply.success, reply.message
    served, _ = msg_to_probability(reply.probability)
    lowered = complete(state, dataset="3du", precision="bfloat16")
    exact = complete(state, dataset="3du")
    np.testing.assert_allclose(served, lowered, atol=1e-6)
    assert np.abs(served - exact).max() > 1e-4  # the other arithmetic
    assert "bfloat16" in (graph.log_dir / "completion_server.log").read_text()
