"""The width timing study (studies.cnn_width) on a small grid: one row per width, ratios to the paper's width."""

import csv

import pytest

from studies.cnn_width import main


def test_cnn_width_writes_a_row_per_width_and_the_plot(tmp_path):
    assert main(["--grids", "40x36x32", "--widths", "16", "8", "--repeats", "1", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "cnn_width.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["grid"], r["width"]) for r in rows] == [("40x36x32", "16"), ("40x36x32", "8")]
    assert float(rows[0]["vs_paper"]) == 1.0
    assert float(rows[1]["vs_paper"]) == pytest.approx(float(rows[1]["seconds"]) / float(rows[0]["seconds"]))
    assert (tmp_path / "cnn_width.png").stat().st_size > 0


def test_cnn_width_names_a_bad_grid():
    with pytest.raises(ValueError, match="--grids"):
        main(["--grids", "40x36", "--repeats", "1"])
