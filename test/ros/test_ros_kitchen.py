"""A real recording through the nodes: 20 frames of the shared 7-Scenes kitchen, imported by
``nbv import-rgbd`` (poses on ``/tf``), replayed by ``launch_scripts/plan_from_bag.py`` (bag_replay ->
integrator with ``pose_source:=tf`` -> nbv_planner) on the recording's box at 4 cm: the grid the
integrator publishes is ``nbv integrate``'s of the same bag on the same box, cell for cell, and the
planner ranks views inside that box with a positive gain."""

from __future__ import annotations

import csv
import os
import re
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
KITCHEN = REPO.parent / "shared" / "data" / "rgbd" / "7scenes_redkitchen"

pytestmark = [
    pytest.mark.slow,  # a multi-process ROS graph
    pytest.mark.skipif(not KITCHEN.is_dir(), reason=f"the shared 7-Scenes kitchen recording is absent ({KITCHEN})"),
]

pytest.importorskip("open3d")
pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("tf2_msgs")

from launch_runs import run_launch_script  # noqa: E402
from test_ros_perception import RosClient  # noqa: E402

from nbv_prob_cnn import cli  # noqa: E402
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED  # noqa: E402
from nbv_prob_cnn.perception import load_grid  # noqa: E402
from nbv_prob_cnn.ros.conversions import msg_to_grid  # noqa: E402

FRAMES = 20
VOXEL = 0.04


def test_the_kitchen_replays_through_the_graph_and_the_planner_plans_on_it(tmp_path, ros_domain):
    bag = tmp_path / "kitchen20"
    imported = ["import-rgbd", "--format", "7scenes", str(KITCHEN), "--max-frames", str(FRAMES), "--no-progress"]
    assert cli.main([*imported, "--out", str(bag)]) == 0
    env = ros_domain(180 + os.getpid() % 10)  # 180..189: no other test uses these
    out = tmp_path / "plan"
    cmd = [sys.executable, str(REPO / "launch_scripts" / "plan_from_bag.py"), "--bag", str(bag), "--bounds", "auto",
           "--voxel", str(VOXEL), "--method", "prob_ig", "--top-k", "3", "--out", str(out),
           "--domain-id", env["ROS_DOMAIN_ID"]]  # fmt: skip
    # the test listens to /nbv/grid while the graph runs (the last grid is the one planned on)
    with RosClient(int(env["ROS_DOMAIN_ID"])) as client, ThreadPoolExecutor(1) as pool:
        launched = pool.submit(run_launch_script, cmd, 150)
        while not launched.done():
            client.executor.spin_once(timeout_sec=0.1)
        run = launched.result()
        grid_msg = client.grid
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "poses from /tf (integrator pose_source:=tf)" in run.stdout
    assert "stopped 5 processes" in run.stdout
    # every frame integrated, none dropped (the replay's own account)
    replay_log = (out / "logs" / "bag_replay.log").read_text()
    line = re.search(r"sent (\d+), integrated (\d+), dropped (\d+)", replay_log)
    assert line and line.groups() == (str(FRAMES), str(FRAMES), "0"), replay_log[-2000:]

    # the grid: nbv integrate's of the same bag on the box the graph used
    assert grid_msg is not None, "no grid on /nbv/grid"
    live, geometry = msg_to_grid(grid_msg)
    offline_path = tmp_path / "offline.npz"
    box = ["--origin", *(repr(float(v)) for v in geometry.origin), "--shape", *(str(n) for n in geometry.shape)]
    assert cli.main(["integrate", "--bag", str(bag), "--voxel", str(VOXEL), *box, "--out", str(offline_path)]) == 0
    offline, origin, _ = load_grid(offline_path)
    np.testing.assert_allclose(origin, geometry.origin, atol=1e-9)
    assert geometry.resolution == pytest.approx(VOXEL)
    counts = {name: int(np.count_nonzero(live == value)) for name, value in (("empty", EMPTY), ("occupied", OCCUPIED))}
    assert counts == {
        "empty": int(np.count_nonzero(offline == EMPTY)),
        "occupied": int(np.count_nonzero(offline == OCCUPIED)),
    }
    assert np.array_equal(live, offline), f"{np.count_nonzero(live != offline)} cells differ"
    # the counters, table and floor in front of the camera (20 frames at 4 cm: 16 269 occupied, 50 707 empty)
    assert counts["occupied"] > 10_000 and counts["empty"] > 2 * counts["occupied"], counts

    # the plan: ranked views inside the box, the best with a positive gain
    with open(out / "ranked_views.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 3
    gains = [float(r["gain"]) for r in rows]
    assert gains == sorted(gains, reverse=True) and gains[0] > 0
    low = np.asarray(geometry.origin)
    high = low + VOXEL * np.asarray(geometry.shape)
    for r in rows:
        position = np.array([float(r["x_m"]), float(r["y_m"]), float(r["z_m"])])
        assert np.all(position >= low) and np.all(position <= high), (position, low, high)
