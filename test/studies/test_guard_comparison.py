"""The plain-vs-guarded table (studies.guard_comparison) on hand-written runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from nbv_prob_cnn.exploration.evaluation import run_path
from studies.guard_comparison import compare


def write_run(path: Path, unknown: list[float]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = ["unknown_fraction,unknown_fraction_all,time_total_s"] + [f"{u},{u},0.1" for u in unknown]
    path.write_text("\n".join(rows) + "\n")


def test_paired_differences_and_early_stops(tmp_path: Path) -> None:
    # two environments; the guarded run of seed 121 stops after 3 views and keeps its last value
    for seed, plain, guarded in ((120, [1.0, 0.8, 0.8, 0.8], [1.0, 0.8, 0.6, 0.5]), (121, [1.0, 0.9, 0.9, 0.9],
                                                                                    [1.0, 0.7, 0.4])):  # fmt: skip
        write_run(run_path(tmp_path, "2d", "prob_ig", seed), plain)
        write_run(run_path(tmp_path, "2d", "prob_ig", seed, guarded=True), guarded)
    table, csv_text = compare("2d", tmp_path, methods=("prob_ig",), views=4, at=(2, 4))
    assert "mean over 2 environments (120, 121)" in table
    # after 4 views: plain (0.8 + 0.9) / 2, guarded (0.5 + 0.4) / 2, differences -0.3 and -0.5
    assert "| prob_ig | plain | 0.8500 | 0.8500 | |" in table
    assert "| prob_ig | guarded | 0.7500 | 0.4500 | 1 |" in table
    assert "| prob_ig | guarded − plain | -0.1000 ± 0.1000 | -0.4000 ± 0.1000 | |" in table
    assert csv_text.splitlines()[3] == "prob_ig,guarded-plain,2,-0.10000,0.10000,-0.40000,0.10000,"
    with pytest.raises(ValueError, match="no environment"):
        compare("2d", tmp_path, methods=("ig",), views=4)
