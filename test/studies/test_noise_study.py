"""The noise study's table from hand-made run logs (means, ratio to the ideal sensor, counts)."""

import csv
import json

import numpy as np
import pytest

from nbv_prob_cnn.exploration.explore import IterationRecord, write_csv
from studies.noise_study import Config, main, summarise, write_table


def _write_run(path, fractions, changed, ruled_out):
    records = [
        IterationRecord(i, f, f, 1.0, 0.5, 0.1, 0.2, 0.2, np.zeros(3), np.zeros(3), np.array([0, 0, 0, 1.0]), c, r)
        for i, (f, c, r) in enumerate(zip(fractions, changed, ruled_out, strict=True))
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_csv(records, path)
    path.with_suffix(".json").write_text(json.dumps({"views": len(fractions)}))


def test_table_by_hand(tmp_path):
    views, seeds = 20, [1, 2]
    ideal = Config("ideal", "cnn_prob", 0.3)
    kinect = Config("kinect_v1", "cnn_prob", 0.3)
    lin = np.linspace(1.0, 0.1, views)
    _write_run(ideal.run_path(tmp_path, "3dt", 1, True), lin, [5] * views, [0] * views)
    _write_run(ideal.run_path(tmp_path, "3dt", 2, True), lin * 0.5, [5] * views, [0] * views)
    # the Kinect runs: seed 1 ends at 0.2, seed 2 at 0.1; two views changed nothing, one pose ruled out
    _write_run(kinect.run_path(tmp_path, "3dt", 1, True), lin * 2, [5] * 18 + [0, 0], [0] * 19 + [1])
    _write_run(kinect.run_path(tmp_path, "3dt", 2, True), lin, [5] * views, [0] * views)
    # the no-walls Kinect runs are missing: that configuration is left out, not half-counted
    rows = summarise([ideal, kinect, Config("kinect_v1", "cnn_prob", None)], "3dt", seeds, views, True, tmp_path)
    assert [(r["sensor"], r["room"]) for r in rows] == [("ideal", "exact (no room)"), ("kinect_v1", "walls_0.3m")]
    ideal_row, kinect_row = rows
    assert ideal_row["unknown_after_20"] == pytest.approx((0.1 + 0.05) / 2)
    assert kinect_row["unknown_after_20"] == pytest.approx((0.2 + 0.1) / 2)
    assert kinect_row["ratio_to_ideal_after_20"] == pytest.approx(0.15 / 0.075)
    assert kinect_row["std_after_20"] == pytest.approx(0.05)
    assert kinect_row["ruled_out_views_mean"] == 0.5 and kinect_row["views_changing_0_cells_mean"] == 1.0
    assert kinect_row["plan_time_mean_s"] == pytest.approx(0.5)
    csv_path, md_path = write_table(rows, tmp_path, "noise_table")
    with open(csv_path) as handle:
        table = list(csv.DictReader(handle))
    assert float(table[1]["ratio_to_ideal_after_20"]) == pytest.approx(2.0)
    assert "| kinect_v1 | cnn_prob | walls 0.3m | 2 |" in md_path.read_text()


def test_command_needs_views_for_the_table(tmp_path):
    with pytest.raises(ValueError, match="--views"):
        main(["--out", str(tmp_path), "--views", "10", "--summarise-only"])
