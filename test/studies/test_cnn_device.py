"""The device timing study (studies.cnn_device) on a small saved state, CPU only (twice: the second
compared with the first)."""

import json

import numpy as np

from studies.cnn_device import main


def test_cnn_device_writes_one_row_per_grid_and_device(tmp_path):
    state = np.where(np.random.default_rng(0).random((40, 36, 32)) < 0.5, -1, 0).astype(np.int8)
    np.save(tmp_path / "state.npy", state)
    assert main(["--state", str(tmp_path / "state.npy"), "--devices", "cpu", "cpu", "--repeats", "1",
                 "--out", str(tmp_path)]) == 0  # fmt: skip
    rows = json.loads((tmp_path / "cnn_device.json").read_text())
    assert [(r["device"], r["grid"]) for r in rows] == [("cpu", "40x36x32"), ("cpu", "40x36x32")]  # smaller than 3DT
    assert "max_abs_diff_vs_cpu" not in rows[0] and rows[1]["max_abs_diff_vs_cpu"] == 0.0
    assert all(r["best_s"] > 0 and r["peak_gpu_mib"] == 0.0 for r in rows)
