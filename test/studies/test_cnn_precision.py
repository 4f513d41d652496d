"""The bfloat16 study (studies.cnn_precision) on a small seen 3DT crop: one row per state, written as CSV
and a summary, with the numbers the docs quote checked loosely (the 3DT planner test holds the tight ones)."""

import csv

import numpy as np

import studies.cnn_precision as study


def _seen_crop(seed: int) -> np.ndarray:
    from nbv_prob_cnn.basics.camera import orientations
    from nbv_prob_cnn.basics.datasets import DATASET_SPECS
    from nbv_prob_cnn.sensing.observe import observe
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", seed)
    rng = np.random.default_rng(seed)
    state = np.full(world.shape, -1, dtype=np.int8)
    free = np.argwhere(world.ground_truth == 0)
    for _ in range(4):
        observe(state, world.ground_truth, free[rng.integers(free.shape[0])],
                orientations(3)[rng.integers(len(orientations(3)))], DATASET_SPECS["3dt"].sensor)  # fmt: skip
    return np.ascontiguousarray(state[32:96, 32:96, :48])


def test_cnn_precision_scores_each_state(tmp_path, monkeypatch, bf16):
    monkeypatch.setattr(study, "held_out_state", _seen_crop)
    assert study.main(["--seeds", "120", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "scores.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 1 and rows[0]["seed"] == "120"
    assert 0.0 < float(rows[0]["max_dp"]) <= 0.01
    assert float(rows[0]["rho_views"]) > 0.99
    assert float(rows[0]["regret"]) <= 0.01 and float(rows[0]["cnn_bf16_s"]) > 0
    assert "| 120 |" in (tmp_path / "summary.md").read_text()
