"""Surfaces out of the integrator node (issue 34, item 4): ``/integrator/save_mesh`` writes the mesh
``nbv integrate --mesh`` writes for the same bag, and ``/integrator/occupied_cells`` carries the
occupied cell centres of the published grid, throttled and only while subscribed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")
pytest.importorskip("rosbags")
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
trimesh = pytest.importorskip("trimesh")

from nbv_prob_cnn_msgs.srv import SaveGrid  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from test_ros_perception import RosClient, assert_clean_stop, domain_id, log_text, stamp_ns  # noqa: E402

from nbv_prob_cnn import cli  # noqa: E402
from nbv_prob_cnn.basics.grid import OCCUPIED  # noqa: E402
from nbv_prob_cnn.perception.bags import read_frames  # noqa: E402
from nbv_prob_cnn.ros.conversions import msg_to_grid  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, wait_for  # noqa: E402

pytestmark = pytest.mark.slow  # a multi-process ROS graph

SAMPLE_BAG = Path(__file__).resolve().parents[2] / "bags" / "3dt_seed1000_sample"


def test_integrator_saves_the_mesh_and_publishes_the_occupied_cells(ros_domain, tmp_path: Path) -> None:
    frames = list(read_frames(SAMPLE_BAG))
    offline_mesh = tmp_path / "offline.ply"
    args = ["integrate", "--bag", str(SAMPLE_BAG), "--out", str(tmp_path / "offline.npz")]
    assert cli.main([*args, "--mesh", str(offline_mesh)]) == 0
    env = ros_domain(domain_id(7))
    clouds: list[PointCloud2] = []
    with NodeGraph(env, log_dir=tmp_path) as graph:
        graph.start_node("integrator", "integrator", {"pose_source": "topic", "cloud_rate_hz": 20.0})
        with RosClient(int(env["ROS_DOMAIN_ID"])) as client:
            client.node.create_subscription(PointCloud2, "/integrator/occupied_cells", clouds.append, 10)
            replay = graph.start_node("bag_replay", "bag_replay", {"bag": str(SAMPLE_BAG), "rate": 10.0})
            grid_msg = client.wait_grid(frames[-1].stamp_ns, timeout_s=60.0)
            last = frames[-1].stamp_ns
            assert client.spin_until(lambda: any(stamp_ns(c.header.stamp) == last for c in clouds), 20.0), (
                f"{len(clouds)} cloud(s), none stamped {last}: " + log_text(tmp_path, "integrator")[-2000:]
            )
            assert wait_for(lambda: replay.poll() is not None, 30.0) and replay.returncode == 0
            # a subscriber that comes after the last frame (RViz opened later) still gets the current cloud
            late: list[PointCloud2] = []
            client.node.create_subscription(PointCloud2, "/integrator/occupied_cells", late.append, 10)
            assert client.spin_until(lambda: any(stamp_ns(c.header.stamp) == last for c in late), 20.0)
            reply = client.call(
                client.node.create_client(SaveGrid, "/integrator/save_mesh"),
                SaveGrid.Request(path=str(tmp_path / "live")),
            )
            assert reply.success, reply.message
            bad = client.call(
                client.node.create_client(SaveGrid, "/integrator/save_mesh"),
                SaveGrid.Request(path=str(tmp_path / "nowhere" / "m.ply")),
            )
            assert not bad.success and "no such directory" in bad.message
        assert_clean_stop(graph)
    # the cloud of the last grid: its occupied cell centres, in the grid's frame
    grid, geometry = msg_to_grid(grid_msg)
    cloud = next(c for c in clouds if stamp_ns(c.header.stamp) == last)
    assert cloud.header.frame_id == "world" and cloud.point_step == 12
    points = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(-1, 3)
    assert len(points) == np.count_nonzero(grid == OCCUPIED)
    cells = np.floor((points - np.asarray(geometry.origin)) / geometry.resolution).astype(int)
    assert np.all(grid[tuple(cells.T)] == OCCUPIED)
    # throttled: at most 20 clouds a second over the replay (the grids come at up to 2 Hz here anyway)
    # (the late subscriber's join sends the last cloud once more, to both)
    assert len(clouds) <= len({stamp_ns(c.header.stamp) for c in clouds}) + 2
    # the node's mesh is the offline one (the same frames fused by the same core)
    live = trimesh.load(tmp_path / "live.ply", process=False)
    offline = trimesh.load(offline_mesh, process=False)
    assert len(live.faces) == len(offline.faces) > 1000
    np.testing.assert_allclose(np.sort(live.vertices, axis=0), np.sort(offline.vertices, axis=0), atol=1e-6)
