"""Tests on one local Ray cluster (a head and one worker node started with `ray start` on this
machine, shared by the tests of this module and stopped at its end):

* `nbv evaluate`: the runs as Ray tasks, results equal to the in-process path;
* `nbv train --ray`: one epoch of a tiny City-CNN data-parallel gives the weights of the
  single-process run on the same data and seeds.

Why the trainings agree: both runs draw the same item order and crops; each of the 2 workers
builds one of the 2 items of a step and DDP averages the two gradients, which is the gradient of
the batch's mean loss. What differs is the order of floating-point sums (per-worker means, then
the all-reduce), so the weights agree to float32 rounding, not bit for bit: tolerance 1e-5 after
4 Adam steps at lr 1e-3 (each step moves a weight by at most about 1e-3).
"""

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
import torch

ray = pytest.importorskip("ray")

from nbv_prob_cnn.completion import city_cache  # noqa: E402
from nbv_prob_cnn.completion import data as data_mod  # noqa: E402
from nbv_prob_cnn.completion.train import TrainConfig, train  # noqa: E402
from nbv_prob_cnn.exploration.evaluation import evaluate, read_run, run_path  # noqa: E402


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _stop(procs: list[subprocess.Popen], grace_s: float = 3.0) -> None:
    """Stop `ray start --block` processes and every process each started (its own session): SIGTERM
    to all at once, SIGKILL to what still runs after ``grace_s``. The nodes are started without
    Ray's SIGTERM drain (RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S=0: nothing of this throwaway cluster
    needs draining); a worker node's `ray start` still took the former 8 s wait to exit."""
    for proc in procs:
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for proc in procs:
        try:
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        with contextlib.suppress(ProcessLookupError):  # children that outlived their `ray start`
            os.killpg(proc.pid, signal.SIGKILL)


def _wait_for_nodes(address: str, count: int) -> None:
    ray.init(address=address, include_dashboard=False, log_to_driver=False)
    try:
        deadline = time.monotonic() + 60
        while len([n for n in ray.nodes() if n["Alive"]]) < count:
            assert time.monotonic() < deadline, "the worker node did not join"
            time.sleep(0.5)
    finally:
        ray.shutdown()


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """Address of a head plus one worker node (1 CPU each), on this machine, once both have
    joined (no auth token: a token left in ~/.ray by another local Ray instance must not decide
    how this cluster runs)."""
    logs = tmp_path_factory.mktemp("ray_cluster_logs")
    ray_cli = str(Path(sys.executable).with_name("ray"))
    port = _free_port()
    temp_dir = tempfile.mkdtemp(prefix="nbvray")  # short: Ray's socket paths have a length limit
    common = ["--num-cpus=1", "--block", "--disable-usage-stats"]
    started = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RAY_AUTH_MODE", "disabled")
        env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S": "0"}
        try:
            with open(logs / "head.log", "w") as log:
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
                    assert time.monotonic() < deadline and started[0].poll() is None, (logs / "head.log").read_text()
                    time.sleep(0.5)
            with open(logs / "worker.log", "w") as log:
                worker_cmd = [ray_cli, "start", f"--address=127.0.0.1:{port}", *common]
                started.append(
                    subprocess.Popen(worker_cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
                )
            address = f"127.0.0.1:{port}"
            _wait_for_nodes(address, 2)
            yield address
        finally:
            _stop(started)
            shutil.rmtree(temp_dir, ignore_errors=True)


@pytest.mark.slow
def test_evaluate_on_a_local_ray_cluster(ray_cluster, tmp_path):
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


def _boxes(dataset: str, seed: int) -> tuple[np.ndarray, int]:
    grid = np.zeros((40, 40), dtype=np.uint8)
    for x, y in np.random.default_rng(seed).integers(0, 34, size=(6, 2)):
        grid[x : x + 5, y : y + 4] = 1
    return grid, 1


@pytest.mark.slow
def test_ray_train_matches_the_single_process_run(ray_cluster, tmp_path, monkeypatch):
    from nbv_prob_cnn.completion.ray_train import train_with_ray

    monkeypatch.setenv("NBV_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(data_mod, "load_environment", _boxes)
    monkeypatch.setattr(data_mod, "current_generator_version", lambda: 1)
    kwargs = {
        "n_train_envs": 1, "n_val_envs": 1, "n_test_envs": 1, "crop": 16, "test_crop": 24, "batch_size": 2,
        "progress": False, "threads": 1, "first_channels": 2, "backend": "numpy", "method": "flat_city_cnn",
    }  # fmt: skip
    # the single-process run also fills the cache (the Ray workers only read it: they do not
    # see this test's stand-in environments)
    local = train(TrainConfig("2d", 1, tmp_path / "local" / "w.pt", device="cpu", **kwargs))
    assert city_cache.CacheLayout.for_training("2d", 16, 24).chunk_path(0, "train").is_file()

    ray_out = tmp_path / "ray" / "w.pt"
    result = train_with_ray(
        TrainConfig("2d", 1, ray_out, workers=2, device=None, **kwargs), address=ray_cluster
    )  # as the CLI

    a = torch.load(tmp_path / "local" / "w.last.ckpt", weights_only=True)
    b = torch.load(tmp_path / "ray" / "w.last.ckpt", weights_only=True)
    assert a["history"][0]["epoch"] == b["history"][0]["epoch"] == 1
    for key, value in a["model"].items():
        torch.testing.assert_close(b["model"][key], value, rtol=0, atol=1e-5, msg=key)
    assert b["history"][0]["train_mse"] == pytest.approx(a["history"][0]["train_mse"], rel=1e-4)
    assert result.epochs_done == 1 and result.validation_mse == pytest.approx(local.validation_mse, rel=1e-4)
    assert np.isfinite(result.test_mse) and (tmp_path / "ray" / "w.md").is_file()
    assert "Spearman" in (tmp_path / "ray" / "w.md").read_text()
