"""NodeGraph.stop and the nodes' stack dumps (nbv_prob_cnn.ros.graph): a process that ignores
SIGINT and SIGTERM leaves its threads' stacks in its log before SIGKILL; a running node writes
its stacks on SIGUSR2 and keeps running."""

from __future__ import annotations

import signal
import sys

import pytest

from nbv_prob_cnn.ros.graph import STACK_DUMP_SIGNAL, NodeGraph, wait_for

#: A process stuck in native code (a read on a pipe nobody writes), deaf to SIGINT and SIGTERM.
STUCK = """
import os, signal, threading
from nbv_prob_cnn.ros.graph import enable_stack_dumps
enable_stack_dumps()
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
def stuck_in_native_code():
    read_end, _write_end = os.pipe()
    print("ready", flush=True)
    os.read(read_end, 1)
helper = threading.Thread(target=threading.Event().wait, name="helper", daemon=True)
helper.start()
stuck_in_native_code()
"""

#: The smallest node run by run_node, as our nodes' mains do.
NODE = """
from rclpy.node import Node
from nbv_prob_cnn.ros.runtime import run_node
raise SystemExit(run_node(lambda: Node("stack_dump_test"), threads=1))
"""


def test_a_process_that_ignores_sigint_and_sigterm_leaves_its_stacks_before_sigkill(tmp_path) -> None:
    graph = NodeGraph(log_dir=tmp_path)
    graph.start("stuck", [sys.executable, "-c", STUCK])
    log = tmp_path / "stuck.log"
    assert wait_for(lambda: "ready" in log.read_text(), 60.0), log.read_text()
    codes = graph.stop(grace_s=0.5)
    assert codes == {"stuck": -signal.SIGKILL}
    text = log.read_text()
    assert "Current thread" in text, text  # faulthandler's dump of every thread
    assert "in stuck_in_native_code" in text, text
    assert text.count("Thread 0x") >= 1, text  # the helper thread too


def test_a_node_writes_its_stacks_on_sigusr2_and_keeps_running(tmp_path, ros_domain) -> None:
    pytest.importorskip("rclpy")
    graph = NodeGraph(ros_domain(231), log_dir=tmp_path)
    try:
        node = graph.start("node", [sys.executable, "-c", NODE])
        log = tmp_path / "node.log"
        assert wait_for(lambda: "heap" in log.read_text(), 120.0), log.read_text()  # run_node's first line
        node.send_signal(STACK_DUMP_SIGNAL)
        assert wait_for(lambda: "Current thread" in log.read_text(), 30.0), log.read_text()
        assert "in run_node" in log.read_text()
        assert node.poll() is None  # the dump does not stop it
    finally:
        codes = graph.stop()
    assert codes == {"node": 0}, (tmp_path / "node.log").read_text()
