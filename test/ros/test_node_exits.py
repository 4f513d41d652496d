"""A launcher never waits on a dead graph (issue 48): :func:`~nbv_prob_cnn.ros.graph.run_graph`
watches its nodes, reports the one that exited with its last error line and its log, stops the
rest and returns :data:`EXIT_NODE_EXITED`; ``timeout_s`` bounds the whole run. The nodes and
clients here are plain Python processes (no ROS): the watching needs none."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from nbv_prob_cnn.ros.graph import (
    EXIT_NODE_EXITED,
    EXIT_TIMED_OUT,
    NodeGraph,
    run_graph,
)
from nbv_prob_cnn.ros.node_exits import last_error_line

#: A node that fails at start-up as our nodes do (run_node logs the error as fatal, exits 1).
FAILING_NODE = """
import sys, time
print("[INFO] [1.0] [nbv_planner]: declaring parameters", flush=True)
time.sleep(0.5)
print("[FATAL] [1.5] [nbv_planner]: cannot start: unknown method 'cnnprob'; expected one of ['ig']", flush=True)
print("[INFO] [1.6] [nbv_planner.summary]: 0 plans", flush=True)
sys.exit(1)
"""
#: A node that runs until it is stopped.
SERVING_NODE = "import time; print('serving', flush=True); time.sleep(600)"


def waiting_client(marker: Path, seconds: float) -> list[str]:
    """A client that waits for the graph ``seconds`` and then writes ``marker`` and exits 0 (as
    the launchers' clients do when the graph never comes: they wait for minutes)."""
    code = f"import time, pathlib; time.sleep({seconds}); pathlib.Path({str(marker)!r}).write_text('done')"
    return [sys.executable, "-c", code]


@pytest.fixture
def env(ros_domain) -> dict[str, str]:
    return ros_domain(227)


def test_a_node_that_dies_at_start_up_ends_the_run_with_its_error_line_and_log(tmp_path, env, capsys) -> None:
    graphs: list[NodeGraph] = []

    def start_nodes(graph: NodeGraph) -> None:
        graphs.append(graph)
        graph.start("integrator", [sys.executable, "-c", SERVING_NODE])
        graph.start("nbv_planner", [sys.executable, "-c", FAILING_NODE])

    marker = tmp_path / "client_finished"
    code = run_graph(start_nodes, waiting_client(marker, 120), env, tmp_path / "logs", "test")
    err = capsys.readouterr().err
    assert code == EXIT_NODE_EXITED, err
    assert not marker.exists(), "the launcher waited for the client instead of stopping it"
    assert "nbv_planner exited (status 1)" in err, err
    assert "[FATAL] [1.5] [nbv_planner]: cannot start: unknown method 'cnnprob'" in err, err
    assert str(tmp_path / "logs" / "nbv_planner.log") in err, err
    assert "integrator exited" not in err, err  # the one stopped by the launcher is not reported
    assert not any(graphs[0].alive().values())


def test_timeout_bounds_the_wait_for_the_graph(tmp_path, env, capsys) -> None:
    graphs: list[NodeGraph] = []

    def start_nodes(graph: NodeGraph) -> None:
        graphs.append(graph)
        graph.start("integrator", [sys.executable, "-c", SERVING_NODE])

    marker = tmp_path / "client_finished"
    code = run_graph(start_nodes, waiting_client(marker, 120), env, tmp_path / "logs", "test", timeout_s=2.0)
    err = capsys.readouterr().err
    assert code == EXIT_TIMED_OUT, err
    assert not marker.exists(), "the launcher waited for the client past --timeout"
    assert "--timeout 2 s passed" in err, err
    assert not any(graphs[0].alive().values())


def test_a_node_that_may_finish_is_not_reported_when_it_ends_well(tmp_path, env, capsys) -> None:
    def start_nodes(graph: NodeGraph) -> None:
        graph.start("bag_replay", [sys.executable, "-c", "print('replayed 3 messages')"], may_exit=True)
        graph.start("integrator", [sys.executable, "-c", SERVING_NODE])

    marker = tmp_path / "client_finished"
    code = run_graph(start_nodes, waiting_client(marker, 3), env, tmp_path / "logs", "test")
    assert code == 0, capsys.readouterr().err
    assert marker.exists()


def test_a_node_that_may_finish_is_reported_when_it_fails(tmp_path, env, capsys) -> None:
    failing = "import sys; print('[ERROR] [2.0] [bag_replay]: no subscriber within 60 s', flush=True); sys.exit(1)"

    def start_nodes(graph: NodeGraph) -> None:
        graph.start("bag_replay", [sys.executable, "-c", failing], may_exit=True)

    marker = tmp_path / "client_finished"
    code = run_graph(start_nodes, waiting_client(marker, 120), env, tmp_path / "logs", "test")
    err = capsys.readouterr().err
    assert code == EXIT_NODE_EXITED, err
    assert "bag_replay exited (status 1): [ERROR] [2.0] [bag_replay]: no subscriber within 60 s" in err, err


def test_a_node_killed_by_a_signal_is_named_with_the_signal(tmp_path, env, capsys) -> None:
    crash = "import os, signal, time; time.sleep(0.5); os.kill(os.getpid(), signal.SIGSEGV)"

    def start_nodes(graph: NodeGraph) -> None:
        graph.start("completion_server", [sys.executable, "-c", "print('Fatal Python error: x', flush=True); " + crash])

    client = [sys.executable, "-c", "import time, sys; time.sleep(2); sys.exit(1)"]
    code = run_graph(start_nodes, client, env, tmp_path / "logs", "test")
    err = capsys.readouterr().err
    assert code == EXIT_NODE_EXITED, err
    assert "completion_server exited (killed by SIGSEGV): Fatal Python error: x" in err, err


def test_last_error_line_picks_what_ended_the_node(tmp_path) -> None:
    log = tmp_path / "node.log"
    log.write_text(
        "[INFO] [1.0] [n]: started\n"
        "[ERROR] [2.0] [n]: a first problem\n"
        "Traceback (most recent call last):\n"
        '  File "x.py", line 1, in <module>\n'
        "nbv_prob_cnn.perception.bags.BagError: no such topic '/camera'\n"
        "\n"
        "[INFO] [3.0] [n.summary]: 0 frames\n"
    )
    assert last_error_line(log) == "nbv_prob_cnn.perception.bags.BagError: no such topic '/camera'"
    log.write_text(
        "[FATAL] [1.0] [n]: cannot start: bad parameter\n"
        "[ERROR] [2.0] [n]: a callback still runs 12 s after shutdown began\n"
        "[INFO] [3.0] [n.summary]: 0 frames\n"
    )
    assert last_error_line(log) == "[FATAL] [1.0] [n]: cannot start: bad parameter"  # what ended it
    log.write_text("[INFO] [1.0] [n]: started\n[INFO] [1.0] [n]: still going\n\n")
    assert last_error_line(log) == "[INFO] [1.0] [n]: still going"  # no error line: the last line
    log.write_text("")
    assert last_error_line(log) == "(its log is empty)"
    assert last_error_line(tmp_path / "missing.log").startswith("(its log cannot be read")
    assert last_error_line(None).startswith("(no log")
