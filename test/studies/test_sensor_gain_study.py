"""The study command of the sensor-aware gain and exact sampling (docs/sensing.md): a short run of
each part and the repeat count by hand."""

import csv

import numpy as np

from studies import sensor_gain_study as study


def test_repeated_views_by_hand(tmp_path):
    path = tmp_path / "run.csv"
    poses = [
        (1, 2, 0, 0, 0, 0, 1),
        (3, 2, 0, 0, 0, 0, 1),
        (3, 2, 0, 0, 0, 0, 1),
        (3, 2, 0, 0, 0, 1, 0),
        (3, 2, 0, 0, 0, 1, 0),
    ]
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["iteration", "unknown_fraction", "x", "y", "z", "qx", "qy", "qz", "qw"])
        for i, pose in enumerate(poses):
            writer.writerow([i, 0.5, *pose])
    assert study.repeated_views(path).tolist() == [False, True, False, True]


def test_both_parts_run_and_summarise(tmp_path):
    out = tmp_path / "study"
    assert study.main(["sampling", "--out", str(out), "--dataset", "2d", "--methods", "prob_ig", "--seeds", "120",
                       "--views", "3"]) == 0  # fmt: skip
    for sampling in ("rounded", "exact"):
        assert (out / "runs" / f"2d_prob_ig_{sampling}_plain_seed120.csv").exists()
    table = (out / "sampling_table_2d.md").read_text()
    assert "| 2d | prob_ig | exact | 1 |" in table and "| 2d | prob_ig | rounded | 1 |" in table
    assert study.main(["returns", "--out", str(out), "--dataset", "2d", "--methods", "prob_ig", "--seeds", "120",
                       "--views", "3", "--rooms", "none"]) == 0  # fmt: skip
    with open(out / "returns_table.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["method"], r["sensor"], r["room"], r["sensor_model"], r["runs"]) for r in rows] == [
        ("prob_ig", "kinect_v1", "no_walls", "paper", "1"),
        ("prob_ig", "kinect_v1", "no_walls", "returns", "1"),
    ]
    for r in rows:
        assert 0.0 < float(r["mean_after_3"]) <= 1.0 and np.isfinite(float(r["ruled_out_mean"]))
