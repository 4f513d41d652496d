"""gain_server beside a real camera and robot: the planning frustum from a D435-like depth
CameraInfo, poses in another frame transformed by TF, and ``score_unknown_cells``."""

from __future__ import annotations

import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("tf2_msgs")

from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import EvaluateViews  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo  # noqa: E402
from test_ros_planning import GEOMETRY, call, pose_msg, random_grid, ros_fixture  # noqa: E402
from test_ros_tf import transform  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from nbv_prob_cnn.basics.grid import probability_with_constant  # noqa: E402
from nbv_prob_cnn.planners.pose_scoring import EVALUATE_RAYS_ACROSS, IN_UNKNOWN_CELL, VALID, score_poses  # noqa: E402
from nbv_prob_cnn.planners.requests import planning_context  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import wait_for  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402
from nbv_prob_cnn.ros.tf_listener import TF_STATIC_QOS  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

ros = ros_fixture(101, 4)  # 101..104: no other test module uses these
#: A RealSense D435-like depth stream: 848 x 480 px, fx = fy = 424 px, principal point at the centre.
D435 = {"width": 848, "height": 480, "fx": 424.0, "cx": 423.5, "cy": 239.5}
#: By hand: 2 atan(424 / 424) = 90°, 2 atan(240 / 424) = 59.0230°.
D435_HFOV, D435_VFOV = 90.0, 2 * math.degrees(math.atan(240 / 424))
PROB_IG = 0.15  # prob_ig's constant probability of unknown cells


def d435_info() -> CameraInfo:
    msg = CameraInfo()
    msg.header.frame_id = "camera_depth_optical_frame"
    msg.width, msg.height = D435["width"], D435["height"]
    msg.k = [D435["fx"], 0.0, D435["cx"], 0.0, D435["fx"], D435["cy"], 0.0, 0.0, 1.0]
    return msg


def scored(state, positions, quats, hfov: float, vfov: float, **kwargs):
    """The core's gains with the given fields of view (the 3DU defaults otherwise), over the rays across each
    pose's image that gain_server scores with by default."""
    context = planning_context("3du", GEOMETRY, "opencl", 0, np.random.default_rng(0), hfov, vfov)
    prob = probability_with_constant(state, PROB_IG)
    return score_poses(state, prob, GEOMETRY, positions, quats, context, rays_across=EVALUATE_RAYS_ACROSS, **kwargs)


def test_d435_intrinsics_give_its_fields_of_view():
    from nbv_prob_cnn.perception import Intrinsics

    intrinsics = Intrinsics(D435["width"], D435["height"], D435["fx"], D435["fx"], D435["cx"], D435["cy"])
    hfov, vfov = intrinsics.fov_deg
    assert hfov == pytest.approx(D435_HFOV, abs=1e-9) and vfov == pytest.approx(59.0230, abs=1e-4)
    # an off-centre principal point: atan(100.5 / 424) + atan(747.5 / 424), by hand 13.334° + 60.437°
    shifted = Intrinsics(848, 480, 424.0, 424.0, 100.0, 239.5)
    assert shifted.fov_deg[0] == pytest.approx(math.degrees(math.atan(100.5 / 424) + math.atan(747.5 / 424)))
    assert shifted.fov_deg[0] == pytest.approx(73.771, abs=1e-3)


def test_gain_server_plans_with_the_camera_info_tf_and_unknown_cells(ros, tmp_path):
    node, graph, context = ros
    graph.start_node("gain_server", "gain_server", {"dataset": "3du", "backend": "opencl"})
    state = random_grid(11)
    node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS).publish(grid_to_msg(state, GEOMETRY))
    rng = np.random.default_rng(5)
    empty = np.argwhere(state == 0)
    cells = empty[rng.choice(empty.shape[0], 40, replace=False)]
    positions = GEOMETRY.cell_centre(cells)
    quats = rng.normal(size=(40, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    request = EvaluateViews.Request(poses=[pose_msg(p, q) for p, q in zip(positions, quats, strict=True)],
                                    method="prob_ig")  # fmt: skip

    def evaluate(req=request):
        return call(node, context, EvaluateViews, "/nbv/evaluate_views", req)

    assert wait_for(lambda: evaluate().success, 60.0, 0.5), "the grid never reached gain_server"
    dataset = scored(state, positions, quats, 0.0, 0.0)
    np.testing.assert_allclose(evaluate().gains, dataset.gains, rtol=1e-6, atol=1e-7)  # no CameraInfo yet

    # the D435's CameraInfo (best effort, as drivers publish it): its 90 x 59 deg frustum from now on
    info_pub = node.create_publisher(CameraInfo, "/camera/depth/camera_info",
                                     QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))  # fmt: skip
    d435 = scored(state, positions, quats, D435_HFOV, D435_VFOV)
    assert np.abs(d435.gains - dataset.gains).max() > 0.01  # the wider frustum sees more

    def with_d435() -> bool:
        info_pub.publish(d435_info())
        return np.allclose(evaluate().gains, d435.gains, rtol=1e-6, atol=1e-7)

    assert wait_for(with_d435, 30.0, 0.5), "gain_server did not take the frustum from CameraInfo"
    log = (tmp_path / "logs" / "gain_server.log").read_text()
    assert "planning sensor: hfov 60.0 deg (data set 3du), vfov 46.0 deg (data set 3du)" in log  # at start-up
    assert "planning sensor from CameraInfo 848x480 px, fx 424 fy 424: hfov 90.0 deg (CameraInfo), vfov 59.0 deg" in log
    # a request's own field of view still wins
    narrow = EvaluateViews.Request(poses=request.poses, method="prob_ig", hfov_deg=30.0, vfov_deg=20.0)
    np.testing.assert_allclose(evaluate(narrow).gains, scored(state, positions, quats, 30.0, 20.0).gains,
                               rtol=1e-6, atol=1e-7)  # fmt: skip

    # poses in the frame 'table' (world -> table: +0.1 m along x, 90 deg about z): moved by TF
    tf_static = node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
    tf_static.publish(TFMessage(transforms=[transform("world", "table", 0, (0.1, 0.0, 0.0),
                                                      (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))]))  # fmt: skip
    # by hand: a point (x, y, z) in 'table' is (0.1 - y, x, z) in 'world'; so world (wx, wy, wz)
    # is table (wy, 0.1 - wx, wz), and the orientation is turned back by -90 deg about z
    in_table = [pose_msg([p[1], 0.1 - p[0], p[2]], quat_mul_z(q, -90.0), frame="table")
                for p, q in zip(positions[:10], quats[:10], strict=True)]  # fmt: skip
    table_request = EvaluateViews.Request(poses=in_table, method="prob_ig")

    def in_table_frame() -> bool:
        reply = evaluate(table_request)
        return reply.success and np.all(np.array(reply.validity) == VALID)

    assert wait_for(in_table_frame, 30.0, 0.5), evaluate(table_request).reasons
    np.testing.assert_allclose(evaluate(table_request).gains, d435.gains[:10], rtol=1e-5, atol=1e-6)
    missing = evaluate(EvaluateViews.Request(poses=[pose_msg(positions[0], quats[0], frame="gripper")],
                                             method="prob_ig"))  # fmt: skip
    assert missing.success and missing.validity[0] != VALID and missing.gains[0] == 0
    assert "'gripper' does not exist" in missing.reasons[0], missing.reasons[0]

    # poses in unknown cells: refused by default, scored with score_unknown_cells
    unknown = np.argwhere(state == -1)
    unknown = unknown[rng.choice(unknown.shape[0], 20, replace=False)]
    u_positions = GEOMETRY.cell_centre(unknown)
    u_request = EvaluateViews.Request(poses=[pose_msg(p, q) for p, q in zip(u_positions, quats[:20], strict=True)],
                                      method="prob_ig")  # fmt: skip
    refused = evaluate(u_request)
    assert list(refused.validity) == [IN_UNKNOWN_CELL] * 20 and not np.any(refused.gains)
    u_request.score_unknown_cells = True
    reply = evaluate(u_request)
    expected = scored(state, u_positions, quats[:20], D435_HFOV, D435_VFOV, score_unknown_cells=True)
    assert list(reply.validity) == [VALID] * 20
    assert all("unknown cell (scored: score_unknown_cells)" in r for r in reply.reasons)
    assert np.asarray(reply.gains).max() > 0.01
    np.testing.assert_allclose(reply.gains, expected.gains, rtol=1e-6, atol=1e-7)
    assert all(graph.alive().values())


def quat_mul_z(quat, degrees: float) -> list[float]:
    """``quat`` (x, y, z, w) turned by ``degrees`` about the world z axis (R_z * R), by scipy."""
    from scipy.spatial.transform import Rotation

    return list((Rotation.from_euler("z", degrees, degrees=True) * Rotation.from_quat(quat)).as_quat())


def test_every_node_defaults_to_the_default_method():
    """Every node with a default method (a request naming none) has the registry's, cnn_surface since
    issue 45, so gain_server and nbv_planner score a pose alike."""
    import dataclasses
    import importlib
    import pkgutil

    import nbv_prob_cnn.ros as ros_package
    from nbv_prob_cnn.planners.registry import DEFAULT_METHOD

    defaults = {}
    for module_info in pkgutil.iter_modules(ros_package.__path__):
        module = importlib.import_module(f"nbv_prob_cnn.ros.{module_info.name}")
        for name, value in vars(module).items():
            if dataclasses.is_dataclass(value) and value.__module__ == module.__name__:
                method = next((f for f in dataclasses.fields(value) if f.name == "method"), None)
                if method is not None:
                    defaults[name] = method.default
    assert {"GainServerConfig", "PlannerConfig"} <= set(defaults)
    assert set(defaults.values()) == {DEFAULT_METHOD} == {"cnn_surface"}, defaults
