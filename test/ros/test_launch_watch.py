"""Issue 48: the launch scripts never wait on a dead graph. A node that dies at start-up ends the
run at once, with exit status 4, the node's last error line and the path of its log; ``--timeout``
bounds the whole run, the wait for the graph included (exit status 124). Before, the scripts' clients
waited up to their 300 s ready timeout and ``--timeout`` bounded only the exploration."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from launch_runs import run_launch_script  # noqa: E402

from nbv_prob_cnn.ros.graph import EXIT_NODE_EXITED, EXIT_TIMED_OUT  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

REPO = Path(__file__).resolve().parents[2]
#: Far below the clients' 300 s wait for the graph: a launcher that waited on its dead graph fails
#: here (run_launch_script stops it and reports that it did not finish).
WAIT_S = 200


def test_explore_sim_ends_when_a_node_dies_at_start_up(tmp_path, ros_domain) -> None:
    out = tmp_path / "run"
    domain = ros_domain(170)["ROS_DOMAIN_ID"]
    # two joint positions for the 9-joint Panda: arm_sim refuses its initial_positions at start-up
    cmd = [sys.executable, str(REPO / "launch_scripts" / "explore_sim.py"), "--views", "1", "--method", "prob_ig",
           "--initial-joints", "0.1", "0.2", "--out", str(out), "--domain-id", domain]  # fmt: skip
    run = run_launch_script(cmd, timeout=WAIT_S)
    assert run.returncode == EXIT_NODE_EXITED, run.stdout[-3000:] + run.stderr[-3000:]
    log = out / "logs" / "arm_sim.log"
    fatal = next(line for line in log.read_text().splitlines() if "[FATAL]" in line)
    assert "initial_positions: expected 9 joint positions" in fatal
    assert f"arm_sim exited (status 1): {fatal.strip()}" in run.stderr, run.stderr
    assert f"its log: {log}" in run.stderr, run.stderr
    assert "stopped 6 processes" in run.stdout, run.stdout


def test_robot_ends_when_a_node_dies_at_start_up(tmp_path, ros_domain) -> None:
    env = ros_domain(171)
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"nbv_planner": {"ros__parameters": {"method": "cnnprob"}}}))
    out = tmp_path / "run"
    cmd = [sys.executable, str(REPO / "launch_scripts" / "robot.py"), "--params-file", str(params),
           "--nodes", "nbv_planner", "--views", "1", "--out", str(out)]  # fmt: skip
    run = run_launch_script(cmd, timeout=WAIT_S, env=env)
    assert run.returncode == EXIT_NODE_EXITED, run.stdout[-3000:] + run.stderr[-3000:]
    log = out / "logs" / "nbv_planner.log"
    assert "[FATAL]" in run.stderr and "unknown method 'cnnprob'" in run.stderr, run.stderr
    assert f"its log: {log}" in run.stderr, run.stderr
    assert "unknown method 'cnnprob'" in log.read_text()


def test_robot_timeout_bounds_the_wait_for_the_graph(tmp_path, ros_domain) -> None:
    """Only the integrator: no Explore server ever comes, the client waits for it."""
    env = ros_domain(172)
    out = tmp_path / "run"
    cmd = [sys.executable, str(REPO / "launch_scripts" / "robot.py"), "--nodes", "integrator", "--views", "1",
           "--timeout", "20", "--out", str(out)]  # fmt: skip
    run = run_launch_script(cmd, timeout=WAIT_S, env=env)
    assert run.returncode == EXIT_TIMED_OUT, run.stdout[-3000:] + run.stderr[-3000:]
    assert "--timeout 20 s passed" in run.stderr, run.stderr
    assert "interrupted before a goal was sent" in run.stdout, run.stdout  # the client was still waiting
    assert "stopped 1 processes" in run.stdout, run.stdout
