"""`nbv evaluate` on a local Ray cluster: a head and one worker started with `ray start` on this
machine (both stopped at the end), the runs as Ray tasks, results equal to the in-process path."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from nbv_prob_cnn.exploration.evaluation import evaluate, read_run, run_path  # noqa: E402


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    """Stop one `ray start --block` and every process it started (its own session)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=8)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    with contextlib.suppress(ProcessLookupError):  # children that outlived their `ray start`
        os.killpg(proc.pid, signal.SIGKILL)


@pytest.fixture
def ray_cluster(tmp_path, monkeypatch):
    """Address of a head plus one worker node (1 CPU each), on this machine (no auth token: a
    token left in ~/.ray by another local Ray instance must not decide how this cluster runs)."""
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    ray_cli = str(Path(sys.executable).with_name("ray"))
    port = _free_port()
    temp_dir = tempfile.mkdtemp(prefix="nbvray")  # short: Ray's socket paths have a length limit
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    common = ["--num-cpus=1", "--block", "--disable-usage-stats"]
    started = []
    try:
        with open(tmp_path / "head.log", "w") as log:
            head_cmd = [ray_cli, "start", "--head", f"--port={port}", "--include-dashboard=false", *common]
            head_cmd.append(f"--temp-dir={temp_dir}")
            started.append(
                subprocess.Popen(head_cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            )
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline and started[0].poll() is None, (tmp_path / "head.log").read_text()
                time.sleep(0.5)
        with open(tmp_path / "worker.log", "w") as log:
            worker_cmd = [ray_cli, "start", f"--address=127.0.0.1:{port}", *common]
            started.append(
                subprocess.Popen(worker_cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            )
        yield f"127.0.0.1:{port}"
    finally:
        for proc in reversed(started):
            _stop(proc)
        shutil.rmtree(temp_dir, ignore_errors=True)


@pytest.mark.slow
def test_evaluate_on_a_local_ray_cluster(ray_cluster, tmp_path):
    ray.init(address=ray_cluster, include_dashboard=False, log_to_driver=False)
    try:
        deadline = time.monotonic() + 60
        while len([n for n in ray.nodes() if n["Alive"]]) < 2:
            assert time.monotonic() < deadline, "the worker node did not join"
            time.sleep(0.5)
    finally:
        ray.shutdown()

    methods, seeds = ["random", "prob_ig"], [120, 121]
    logs = evaluate("3du", methods, seeds, 3, tmp_path / "ray", progress=False, address=ray_cluster, backend="opencl")
    local = evaluate("3du", methods, seeds, 3, tmp_path / "local", progress=False, workers=0, backend="opencl")
    for method in methods:
        for got, expected in zip(logs[method], local[method], strict=True):
            np.testing.assert_array_equal(got.unknown_fraction, expected.unknown_fraction)
    paths = [run_path(tmp_path / "ray", "3du", m, s) for m in methods for s in seeds]
    assert all(json.loads(p.with_suffix(".json").read_text())["views"] == 3 for p in paths)
    mtimes = [p.stat().st_mtime_ns for p in paths]
    evaluate("3du", methods, seeds, 3, tmp_path / "ray", progress=False, address=ray_cluster)  # all finished
    assert [p.stat().st_mtime_ns for p in paths] == mtimes
    assert len(read_run(paths[0], 2).unknown_fraction) == 2  # a shorter table reads the same runs
