"""The coverage side of ``nbv evaluate``'s tables, on hand-made runs: views to a level counted
over the runs that reach it, runs that never do counted beside, run CSVs without the column said
so, and the CSVs, the plot and the read-back of old and new run files."""

from __future__ import annotations

import csv
import json

import numpy as np

from nbv_prob_cnn.exploration.coverage_tables import (
    coverage_table,
    save_coverage_plot,
    write_coverage_runs_csv,
    write_views_to_coverage_csv,
)
from nbv_prob_cnn.exploration.evaluation import RunLog, read_run, write_summary_csv


def run(coverage: list[float] | None, seed: int = 120, chamfer: dict | None = None) -> RunLog:
    n = 4 if coverage is None else len(coverage)
    flat = np.linspace(0.5, 0.2, n)
    return RunLog(flat, flat, np.zeros(n), None if coverage is None else np.array(coverage), chamfer, seed)


def rows(path) -> list[dict[str, str]]:
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_views_to_a_level_count_the_runs_that_never_reach_it(tmp_path):
    logs = {
        # run 1 reaches 80 % at view 2, 90 % at 3, 95 % at 4; run 2 reaches 80 % at view 4, never 90 %
        "a": [run([0.5, 0.8, 0.9, 0.96], 120), run([0.2, 0.5, 0.7, 0.85], 121)],
        "b": [run(None, 120), run(None, 121)],  # run CSVs from before the column
        "c": [run([0.9, 0.9, 0.9, 0.9], 120), run(None, 121)],
    }
    table = coverage_table(logs, [2, 4]).splitlines()
    assert table[0] == (
        "| method | runs | coverage after 2 views | coverage after 4 views | views to 80 % | views to 90 % "
        "| views to 95 % |"
    )
    # after 2 views: mean (0.8, 0.5) = 0.65, std 0.15; after 4: (0.96, 0.85) -> 0.905 ± 0.055
    # views to 80 %: (2, 4) -> 3.0 ± 1.0, 2 of 2; to 90 %: only run 1, at 3; to 95 %: run 1 at 4
    assert table[2] == (
        "| a | 2 | 0.6500 ± 0.1500 | 0.9050 ± 0.0550 | 3.0 ± 1.0 (2/2) | 3.0 ± 0.0 (1/2) | 4.0 ± 0.0 (1/2) |"
    )
    assert table[3] == "| b | 2 | " + " | ".join(["n/a (run CSV predates the column)"] * 5) + " |"
    assert table[4] == "| c | 2 | " + " | ".join(["n/a (1 of 2 run CSVs predate the column)"] * 5) + " |"
    assert "a run that never reaches it counts in the runs, not in the mean" in table[-1]
    assert "Chamfer" not in table[0]

    write_views_to_coverage_csv(logs, tmp_path / "levels.csv")
    levels = rows(tmp_path / "levels.csv")
    assert levels[0] == {"method": "a", "level": "0.8", "runs": "2", "runs_reaching": "2", "mean_views": "3.00",
                         "std_views": "1.00", "median_views": "3", "max_views": "4"}  # fmt: skip
    assert levels[1]["runs_reaching"] == "1" and levels[1]["mean_views"] == "3.00"
    assert levels[3]["runs_reaching"] == "n/a"  # b
    write_coverage_runs_csv(logs, tmp_path / "runs.csv")
    runs = rows(tmp_path / "runs.csv")
    assert [r["views_to_90"] for r in runs[:2]] == ["3", "never"]
    assert runs[1]["final_surface_coverage"] == "0.850000" and runs[1]["seed"] == "121"
    assert runs[2]["views_to_80"] == "n/a" and runs[2]["chamfer_m"] == ""

    write_summary_csv(logs, 4, tmp_path / "summary.csv")
    summary = rows(tmp_path / "summary.csv")
    assert summary[1]["mean_surface_coverage"] == "0.650000" and summary[1]["std_surface_coverage"] == "0.150000"
    assert summary[4]["mean_surface_coverage"] == "n/a" and summary[4]["mean_unknown_fraction"] == "0.500000"

    png = save_coverage_plot(logs, 4, "3DT", tmp_path / "coverage.png")
    assert png == tmp_path / "coverage.png" and png.stat().st_size > 10_000
    assert save_coverage_plot({"b": logs["b"]}, 4, "3DT", tmp_path / "none.png") is None


def test_a_run_that_stopped_early_keeps_its_last_coverage():
    logs = {"a": [run([0.5, 0.85]), run([0.5, 0.6, 0.7, 0.8])]}
    # padded: run 1 stays at 0.85 after view 2; it never reaches 90 % (it has no more views)
    assert coverage_table(logs, [4]).splitlines()[2] == (
        "| a | 2 | 0.8250 ± 0.0250 | 3.0 ± 1.0 (2/2) | never (0/2) | never (0/2) |"
    )


def test_chamfer_column_when_runs_measured_one():
    one = {"distance_m": 0.004, "accuracy_m": 0.001, "completeness_m": 0.007}
    two = {"distance_m": 0.006, "accuracy_m": 0.002, "completeness_m": 0.010}
    logs = {"a": [run([0.9], chamfer=one), run([0.9], chamfer=two)], "b": [run([0.9], chamfer=one), run([0.9])]}
    table = coverage_table(logs, [1]).splitlines()
    assert table[0].endswith("| Chamfer after the last view, mm (accuracy / completeness) |")
    assert table[2].endswith("| 5.00 ± 1.00 (1.50 / 8.50) |")
    assert table[3].endswith("| n/a (1 of 2 runs without one) |")


def test_read_run_of_an_old_and_a_new_csv(tmp_path):
    old = tmp_path / "3dt_random_seed123.csv"
    old.write_text("iteration,unknown_fraction,unknown_fraction_all,time_total_s\n0,0.9,0.95,0\n1,0.8,0.9,0.1\n")
    log = read_run(old)
    assert log.surface_coverage is None and log.chamfer is None and log.seed == 123
    new = tmp_path / "3dt_random_seed124.csv"
    new.write_text("iteration,unknown_fraction,unknown_fraction_all,time_total_s,surface_coverage\n"
                   "0,0.9,0.95,0,0.25\n1,0.8,0.9,0.1,0.5\n")  # fmt: skip
    new.with_suffix(".json").write_text(json.dumps({"views": 2, "chamfer": {"distance_m": 0.01}}))
    log = read_run(new, 1)
    np.testing.assert_array_equal(log.surface_coverage, [0.25])
    assert log.chamfer == {"distance_m": 0.01} and log.seed == 124
