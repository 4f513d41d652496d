"""`nbv train --ray`: one epoch of a tiny City-CNN data-parallel on a local Ray cluster (a head
and one worker node started with `ray start`, as in test_evaluation_ray) gives the weights of the
single-process run on the same data and seeds.

Why they agree: both runs draw the same item order and crops; each of the 2 workers builds one of
the 2 items of a step and DDP averages the two gradients, which is the gradient of the batch's
mean loss. What differs is the order of floating-point sums (per-worker means, then the
all-reduce), so the weights agree to float32 rounding, not bit for bit: tolerance 1e-5 after
4 Adam steps at lr 1e-3 (each step moves a weight by at most about 1e-3).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

ray = pytest.importorskip("ray")
pytest.importorskip("ray.train.torch")

from test_evaluation_ray import ray_cluster  # noqa: E402, F401 - the fixture

from nbv_prob_cnn.completion import city_cache  # noqa: E402
from nbv_prob_cnn.completion import data as data_mod  # noqa: E402
from nbv_prob_cnn.completion.train import train  # noqa: E402


def _boxes(dataset: str, seed: int) -> tuple[np.ndarray, int]:
    grid = np.zeros((40, 40), dtype=np.uint8)
    for x, y in np.random.default_rng(seed).integers(0, 34, size=(6, 2)):
        grid[x : x + 5, y : y + 4] = 1
    return grid, 1


@pytest.mark.slow
def test_ray_train_matches_the_single_process_run(ray_cluster, tmp_path, monkeypatch):  # noqa: F811
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
    local = train("2d", 1, tmp_path / "local" / "w.pt", device="cpu", **kwargs)
    assert city_cache.CacheLayout.for_training("2d", 16, 24).chunk_path(0, "train").is_file()

    ray.init(address=ray_cluster, include_dashboard=False, log_to_driver=False)
    try:
        deadline = time.monotonic() + 60
        while len([n for n in ray.nodes() if n["Alive"]]) < 2:
            assert time.monotonic() < deadline, "the worker node did not join"
            time.sleep(0.5)
    finally:
        ray.shutdown()
    ray_out = tmp_path / "ray" / "w.pt"
    result = train_with_ray("2d", 1, ray_out, workers=2, address=ray_cluster, device=None, **kwargs)  # as the CLI

    a = torch.load(tmp_path / "local" / "w.last.ckpt", weights_only=True)
    b = torch.load(tmp_path / "ray" / "w.last.ckpt", weights_only=True)
    assert a["history"][0]["epoch"] == b["history"][0]["epoch"] == 1
    for key, value in a["model"].items():
        torch.testing.assert_close(b["model"][key], value, rtol=0, atol=1e-5, msg=key)
    assert b["history"][0]["train_mse"] == pytest.approx(a["history"][0]["train_mse"], rel=1e-4)
    assert result.epochs_done == 1 and result.validation_mse == pytest.approx(local.validation_mse, rel=1e-4)
    assert np.isfinite(result.test_mse) and (tmp_path / "ray" / "w.md").is_file()
    assert "Spearman" in (tmp_path / "ray" / "w.md").read_text()
