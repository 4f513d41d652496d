"""``octomap_bridge`` (issue 46): the grid on ``/nbv/grid`` comes out as an ``octomap_msgs/Octomap`` and a
MoveIt ``PlanningScene`` diff that OctoMap's own library (``octomap-python``) reads back as the
grid's cells; unknown cells occupied by default, left out with ``unknown_as_occupied:=false``; an
unchanged grid is not sent again; a burst of grids is thinned by the rate limit, the last one sent."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("octomap_msgs")
moveit_msgs = pytest.importorskip("moveit_msgs")
octomap = pytest.importorskip("octomap", reason="OctoMap's Python binding (octomap-python) is not installed")

from moveit_msgs.msg import PlanningScene  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from octomap_msgs.msg import Octomap  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from test_ros_perception import RosClient, assert_clean_stop, domain_id, log_text  # noqa: E402

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg, time_msg  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402

pytestmark = pytest.mark.slow  # a multi-process ROS graph

RES = 0.05
SHAPE = (12, 10, 8)


def random_grid(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=SHAPE, p=[0.3, 0.5, 0.2])
    state[0:4, 0:4, 0:4] = 0  # an aligned block: a pruned leaf
    return state


def library_tree(msg: Octomap, tmp_path: Path):
    """The library's tree of the message, read through a .bt file whose header counts the nodes
    from the bytes by hand: 2 bytes per inner node, plus each child field 01 or 10 (a leaf)."""
    data = np.asarray(msg.data, dtype=np.int8).view(np.uint8)
    fields = np.stack([(data >> shift) & 3 for shift in (0, 2, 4, 6)])
    nodes = len(data) // 2 + int(np.count_nonzero((fields == 1) | (fields == 2)))
    path = tmp_path / f"msg_{msg.header.stamp.sec}.bt"
    header = f"# Octomap OcTree binary file\nid {msg.id}\nsize {nodes}\nres {msg.resolution!r}\ndata\n"
    path.write_bytes(header.encode() + data.tobytes())
    tree = octomap.OcTree(msg.resolution)
    assert tree.readBinary(str(path).encode()), "the library refused the message's tree"
    return tree


def labels(tree, corner) -> np.ndarray:
    centres = (np.argwhere(np.ones(SHAPE, dtype=bool)) + 0.5) * RES + np.asarray(corner, dtype=float)
    return np.asarray(tree.getLabels(centres)).reshape(SHAPE).astype(np.int8)


class Bridge:
    """The test's side of one bridge: publishes grids, collects octomaps and planning scenes."""

    def __init__(self, client: RosClient, namespace: str = "") -> None:
        self.octomaps: list[Octomap] = []
        self.scenes: list[PlanningScene] = []
        node = client.node
        self.client = client
        self.grid_pub = node.create_publisher(VoxelGrid, f"{namespace}/nbv/grid", GRID_QOS)
        node.create_subscription(Octomap, f"{namespace}/octomap_bridge/octomap", self.octomaps.append, GRID_QOS)
        node.create_subscription(PlanningScene, f"{namespace}/planning_scene", self.scenes.append, QoSProfile(depth=50))

    def send(self, state: np.ndarray, stamp_s: int, origin=(0.1, -0.2, 0.05), resolution: float = RES) -> None:
        geometry = GridGeometry(origin, resolution, state.shape)
        self.grid_pub.publish(grid_to_msg(state, geometry, "world", time_msg(stamp_s * 10**9)))

    def octomap_at(self, stamp_s: int, timeout_s: float = 30.0) -> Octomap:
        def found():
            return next((m for m in self.octomaps if m.header.stamp.sec == stamp_s), None)

        assert self.client.spin_until(lambda: found() is not None, timeout_s), (
            f"no octomap stamped {stamp_s} s; got {[m.header.stamp.sec for m in self.octomaps]}"
        )
        return found()

    def scene_at(self, stamp_s: int, timeout_s: float = 30.0) -> PlanningScene:
        def found():
            return next((s for s in self.scenes if s.world.octomap.header.stamp.sec == stamp_s), None)

        assert self.client.spin_until(lambda: found() is not None, timeout_s), f"no planning scene stamped {stamp_s} s"
        return found()


def test_the_bridge_publishes_the_grid_as_an_octomap_and_a_planning_scene(ros_domain, tmp_path: Path) -> None:
    env = ros_domain(domain_id(11))
    with NodeGraph(env, log_dir=tmp_path) as graph:
        graph.start_node("octomap_bridge", "octomap_bridge", {"planning_scene": True, "max_rate_hz": 2.0})
        graph.start_node("bridge_free", "octomap_bridge", {"unknown_as_occupied": False}, namespace="/free")
        with RosClient(int(env["ROS_DOMAIN_ID"])) as client:
            main, free = Bridge(client), Bridge(client, "/free")
            first = random_grid(1)
            main.send(first, 1)
            free.send(first, 1)
            octo = main.octomap_at(1)
            assert (octo.header.frame_id, octo.id, octo.binary, octo.resolution) == ("world", "OcTree", True, RES)
            # the default: unknown cells in as occupied, nothing outside the grid
            tree = library_tree(octo, tmp_path)
            np.testing.assert_array_equal(labels(tree, (0.1, -0.2, 0.05)), np.where(first == -1, 1, first))
            assert np.all(labels(tree, (0.1 + SHAPE[0] * RES, -0.2, 0.05)) == -1)
            scene = main.scene_at(1)
            assert scene.is_diff and scene.world.octomap.header.frame_id == "world"
            assert scene.world.octomap.origin.position.x == 0.0 and bytes(scene.world.octomap.octomap.data) == bytes(
                octo.data
            )  # the corner is on the lattice: the same tree, not moved
            # unknown_as_occupied:=false: unknown cells stay unknown
            free_tree = library_tree(free.octomap_at(1), tmp_path)
            np.testing.assert_array_equal(labels(free_tree, (0.1, -0.2, 0.05)), first)

            # the same cells again (the integrator's republishing, a new stamp) are not sent; a change is
            main.send(first, 2)
            second = random_grid(2)
            main.send(second, 3)
            tree = library_tree(main.octomap_at(3), tmp_path)
            np.testing.assert_array_equal(labels(tree, (0.1, -0.2, 0.05)), np.where(second == -1, 1, second))
            assert 2 not in [m.header.stamp.sec for m in main.octomaps]

            # a burst of grids: thinned to the rate, the last one always sent
            for stamp in range(10, 20):
                main.send(random_grid(stamp), stamp)
            last = library_tree(main.octomap_at(19), tmp_path)
            np.testing.assert_array_equal(
                labels(last, (0.1, -0.2, 0.05)), np.where(random_grid(19) == -1, 1, random_grid(19))
            )
            burst = [m for m in main.octomaps if 10 <= m.header.stamp.sec < 20]
            assert len(burst) < 10, [m.header.stamp.sec for m in burst]

            # a corner off the 5 cm lattice: the planning scene places the tree exactly by its origin
            off = random_grid(30)
            main.send(off, 30, origin=(0.113, -0.2, 0.05))
            scene = main.scene_at(30)
            origin = scene.world.octomap.origin.position
            assert (origin.x, origin.y, origin.z) == pytest.approx((0.113, -0.2, 0.05))
            placed = library_tree(scene.world.octomap.octomap, tmp_path)
            np.testing.assert_array_equal(labels(placed, (0.0, 0.0, 0.0)), np.where(off == -1, 1, off))
            # ... and the octomap in the grid's frame moves the cells onto the lattice (by 13 mm here, < half a cell)
            moved = library_tree(main.octomap_at(30), tmp_path)
            np.testing.assert_array_equal(labels(moved, (0.1, -0.2, 0.05)), np.where(off == -1, 1, off))
        assert "moved by [-13.0, 0.0, 0.0] mm" in log_text(tmp_path, "octomap_bridge")
        assert_clean_stop(graph)


def test_gain_server_plans_on_the_octomap_the_bridge_publishes(ros_domain, tmp_path: Path) -> None:
    """The chain a user with octomap_server runs, with our bridge as the map's publisher: the grid
    -> octomap_bridge -> gain_server (grid_source:=octomap) ranks the same views as on the grid itself."""
    from nbv_prob_cnn_msgs.srv import RankViews
    from test_ros_planning import call

    geometry = GridGeometry((8 * 0.0116, -16 * 0.0116, 0.0), 0.0116, (48, 48, 40))  # on the 1.16 cm lattice
    rng = np.random.default_rng(4)
    state = np.full(geometry.shape, -1, dtype=np.int8)
    state[6:42, 6:42, 4:30] = rng.choice(np.array([-1, 0, 0, 0, 1], dtype=np.int8), size=(36, 36, 26))
    box_max = [geometry.origin[i] + geometry.shape[i] * geometry.resolution for i in range(3)]
    env = ros_domain(domain_id(13))
    with NodeGraph(env, log_dir=tmp_path) as graph:
        graph.start_node("octomap_bridge", "octomap_bridge", {"unknown_as_occupied": False})
        graph.start_node("gain_server", "gain_server", {
            "dataset": "3du", "backend": "opencl", "method": "prob_ig", "grid_source": "octomap",
            "octomap_topic": "/octomap_bridge/octomap", "octomap_box_min": list(geometry.origin),
            "octomap_box_max": box_max,
        })  # fmt: skip
        with RosClient(int(env["ROS_DOMAIN_ID"])) as client:
            Bridge(client).send(state, 5, origin=geometry.origin, resolution=geometry.resolution)
            direct = RankViews.Request(grid=grid_to_msg(state, geometry, "world"), method="prob_ig", top_k=20)
            on_grid = call(client.node, client.context, RankViews, "/nbv/rank_views", direct)
            assert on_grid.success, on_grid.message
            latest = RankViews.Request(method="prob_ig", top_k=20)  # no grid: the server's own, from the OctoMap
            deadline, on_octomap = time.monotonic() + 60.0, None
            while time.monotonic() < deadline:
                on_octomap = call(client.node, client.context, RankViews, "/nbv/rank_views", latest)
                if on_octomap.success or "no grid received yet" not in on_octomap.message:
                    break
                time.sleep(0.5)
            assert on_octomap is not None and on_octomap.success, on_octomap and on_octomap.message
            assert len(on_octomap.ranked) == len(on_grid.ranked) == 20
            for a, b in zip(on_octomap.ranked, on_grid.ranked, strict=True):
                assert a.gain == pytest.approx(b.gain, rel=1e-6)
                assert a.pose.header.frame_id == "world"
                p, q = a.pose.pose.position, b.pose.pose.position
                assert (p.x, p.y, p.z) == pytest.approx((q.x, q.y, q.z), abs=1e-6)
        assert_clean_stop(graph)
