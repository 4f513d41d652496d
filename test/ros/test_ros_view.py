"""``bag_record planning:=true`` records the planning output (markers, next best views, the grid as
a PointCloud2 of occupied cells) and ``nbv view`` renders such a run to PNG and CSV."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from geometry_msgs.msg import PoseStamped, TransformStamped  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from test_ros_perception import RosClient, domain_id  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from nbv_prob_cnn import cli  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph  # noqa: E402
from nbv_prob_cnn.ros.markers import planning_markers  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402
from nbv_prob_cnn.viz.recorded_run import gain_heat_map, load_run  # noqa: E402

GEOMETRY = GridGeometry((0.1, 0.2, 0.0), 0.05, (8, 8, 4))


def test_gain_heat_map_keeps_the_best_gain_per_cell():
    candidates = np.array([[0.00, 0.00, 1, 0.2], [0.01, 0.01, 1, 0.7], [0.05, 0.00, 1, 0.4]])
    cells, corner, best = gain_heat_map(candidates, 0.02)
    assert corner.tolist() == [0.0, 0.0]
    assert {tuple(c): g for c, g in zip(cells.tolist(), best.tolist(), strict=True)} == {(0, 0): 0.7, (2, 0): 0.4}


@pytest.mark.slow
def test_recorded_run_renders(tmp_path: Path, ros_domain):
    env = ros_domain(domain_id(5))
    state = np.zeros(GEOMETRY.shape, np.int8)
    occupied_cells = np.array([[1, 2, 0], [5, 5, 3], [7, 0, 1]])
    state[tuple(occupied_cells.T)] = 1
    views = [(np.array([0.3, 0.4, 0.1]), np.array([0, 0, 0, 1.0]), 2.0),
             (np.array([0.31, 0.41, 0.1]), np.array([0, 0, 0, 1.0]), 1.0),
             (np.array([0.5, 0.2, 0.1]), np.array([0, 0, 0, 1.0]), 0.5)]  # fmt: skip
    bag = tmp_path / "run"
    with NodeGraph(env, log_dir=tmp_path / "logs") as graph, RosClient(int(env["ROS_DOMAIN_ID"])) as client:
        graph.start_node("bag_record", "bag_record", {"output": str(bag), "planning": True})
        grid_pub = client.node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS)
        marker_pub = client.node.create_publisher(MarkerArray, "/nbv/markers", 10)
        nbv_pub = client.node.create_publisher(PoseStamped, "/nbv/next_best_view", 10)
        pose_pub = client.node.create_publisher(TransformStamped, "/camera/pose", 10)
        publishers = (grid_pub, marker_pub, nbv_pub, pose_pub)
        assert client.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in publishers), 40.0)
        client.spin_until(lambda: False, 0.5)
        grid_pub.publish(grid_to_msg(state, GEOMETRY))
        stamp = client.node.get_clock().now().to_msg()
        marker_pub.publish(planning_markers("world", stamp, views, 60.0, 45.0, 0.1, 0.05))
        nbv = PoseStamped()
        nbv.header.frame_id = "world"
        nbv.pose.position.x, nbv.pose.position.y, nbv.pose.position.z = 0.3, 0.4, 0.1
        nbv_pub.publish(nbv)
        camera = TransformStamped()
        camera.header.frame_id = "world"
        camera.transform.translation.x, camera.transform.translation.y, camera.transform.translation.z = 0.2, 0.1, 0.3
        camera.transform.rotation.w = 1.0
        pose_pub.publish(camera)
        client.spin_until(lambda: False, 1.5)
    run = load_run(bag)
    expected = GEOMETRY.cell_centre(occupied_cells)
    order = np.lexsort(run.occupied.T[::-1])
    np.testing.assert_allclose(run.occupied[order], expected[np.lexsort(expected.T[::-1])], atol=1e-6)
    np.testing.assert_allclose(run.candidates[:, 3], [1.0, 0.5, 0.25], atol=1e-6)  # gain / best
    np.testing.assert_allclose(run.candidates[:, :3], [v[0] for v in views], atol=1e-6)
    assert run.next_best_views.tolist() == [[0.3, 0.4, 0.1]]
    np.testing.assert_allclose(run.camera_positions, [[0.2, 0.1, 0.3]])

    out = tmp_path / "view" / "run.png"
    assert cli.main(["view", "--bag", str(bag), "--out", str(out), "--cell", "0.02"]) == 0
    assert out.stat().st_size > 10_000
    with open(out.with_suffix(".csv")) as handle:
        rows = list(csv.DictReader(handle))
    # the two first candidates share a 2 cm cell: the better one (1.0) is kept
    assert sorted(float(r["best_relative_gain"]) for r in rows) == [0.25, 1.0]

    broken = tmp_path / "broken"
    shutil.copytree(bag, broken)
    mcap = next(broken.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    assert cli.main(["view", "--bag", str(broken), "--out", str(tmp_path / "broken.png")]) == 2  # input refused
