"""``nbv evaluate --replay``: stored runs taken again view by view give back their CSV, with the
surface coverage they lacked (and the Chamfer distance when asked); a run that does not replay is
refused."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest

from nbv_prob_cnn.exploration.evaluation import CHAMFER_KEY, evaluate, run_path, run_status
from nbv_prob_cnn.exploration.replay import DIFFERENCE_KEY, REPLAY_KEY

METHODS = ["random", "prob_ig"]


def strip_coverage(path) -> None:
    """Rewrite a run CSV as runs were written before the surface_coverage column."""
    with open(path, newline="") as handle:
        table = list(csv.reader(handle))
    column = table[0].index("surface_coverage")
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows([row[:column] + row[column + 1 :] for row in table])


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """Two 3DU runs of 4 views (with the coverage column) and the same runs without it."""
    root = tmp_path_factory.mktemp("replay")
    evaluate("3du", METHODS, [120], 4, root / "new" / "3du", progress=False, workers=0)
    shutil.copytree(root / "new", root / "old")
    for method in METHODS:
        strip_coverage(run_path(root / "old" / "3du", "3du", method, 120))
    return root


def test_replay_gives_back_the_run_with_its_coverage(stored, tmp_path):
    old = evaluate("3du", METHODS, [120], 4, stored / "old" / "3du", progress=False, workers=0)
    assert old["prob_ig"][0].surface_coverage is None  # read back, not redone: the column is not required
    logs = evaluate("3du", METHODS, [120], 4, tmp_path, progress=False, workers=0, replay=stored / "old" / "3du")
    for method in METHODS:
        replayed, made = run_path(tmp_path, "3du", method, 120), run_path(stored / "new" / "3du", "3du", method, 120)
        assert replayed.read_bytes() == made.read_bytes()  # every field, the coverage included
        meta = json.loads(replayed.with_suffix(".json").read_text())
        assert meta[REPLAY_KEY] == str(run_path(stored / "old" / "3du", "3du", method, 120))
        assert meta[DIFFERENCE_KEY] <= 5e-7  # a run of today's code replays to the CSV's six decimals
        assert CHAMFER_KEY not in meta
    coverage = logs["prob_ig"][0].surface_coverage
    assert np.all(np.diff(coverage) >= 0) and coverage[-1] > 0


def test_replay_measures_the_chamfer_distance(stored, tmp_path):
    logs = evaluate("3du", ["prob_ig"], [120], 4, tmp_path, progress=False, workers=0,
                    chamfer=True, replay=stored / "old" / "3du")  # fmt: skip
    chamfer = logs["prob_ig"][0].chamfer
    assert chamfer["views"] == 4 and chamfer["mesh_vertices"] > 0
    assert 0 < chamfer["accuracy_m"] < chamfer["completeness_m"]  # what it saw lies on the objects; most it did not see
    path = run_path(tmp_path, "3du", "prob_ig", 120)
    assert run_status(path, 4, chamfer=True) != "no chamfer"
    assert run_status(run_path(stored / "new" / "3du", "3du", "prob_ig", 120), 4, chamfer=True) == "no chamfer"
    with pytest.raises(ValueError, match="needs a 3D data set"):
        evaluate("2d", ["random"], [120], 2, tmp_path / "2d", progress=False, workers=0, chamfer=True)


def test_a_run_that_does_not_replay_is_refused(stored, tmp_path):
    source = tmp_path / "source" / "3du"
    shutil.copytree(stored / "old" / "3du", source)
    path = run_path(source, "3du", "random", 120)
    with open(path, newline="") as handle:
        table = list(csv.reader(handle))
    column = table[0].index("unknown_fraction")
    table[3][column] = "0.123456"  # view 2
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows(table)
    with pytest.raises(ValueError, match="view 2: the replay gives unknown fractions"):
        evaluate("3du", ["random"], [120], 4, tmp_path / "out", progress=False, workers=0, replay=source)
    with pytest.raises(ValueError, match="seed121.csv: missing"):
        evaluate("3du", ["random"], [121], 4, tmp_path / "out", progress=False, workers=0, replay=source)
    with pytest.raises(ValueError, match="short"):
        evaluate("3du", ["random"], [120], 5, tmp_path / "out", progress=False, workers=0, replay=source)


def test_a_run_planned_in_out_is_read_beside_the_replayed_ones(stored, tmp_path):
    """A method the replayed folder lacks (planned into ``out`` first) is read back from ``out``, not
    refused, so one table holds the replayed methods and the new one."""
    source = tmp_path / "source" / "3du"
    (source / "runs").mkdir(parents=True)
    shutil.copy(run_path(stored / "old" / "3du", "3du", "random", 120), source / "runs")
    out = tmp_path / "out"
    evaluate("3du", ["prob_ig"], [120], 4, out, progress=False, workers=0)  # planned here, not in source
    planned = run_path(out, "3du", "prob_ig", 120).read_bytes()
    logs = evaluate("3du", METHODS, [120], 4, out, progress=False, workers=0, replay=source)
    assert run_path(out, "3du", "prob_ig", 120).read_bytes() == planned  # read back, not redone
    assert REPLAY_KEY in json.loads(run_path(out, "3du", "random", 120).with_suffix(".json").read_text())
    assert logs["random"][0].surface_coverage is not None and len(logs["prob_ig"]) == 1
    with pytest.raises(ValueError, match="missing"):  # neither in source nor planned in out
        evaluate("3du", ["ig"], [120], 4, out, progress=False, workers=0, replay=source)


def test_evaluate_command_writes_the_coverage_table_csvs_and_plot(stored, tmp_path, capsys):
    from nbv_prob_cnn.cli import main

    args = ["evaluate", "--dataset", "3du", "--methods", *METHODS, "--seeds", "120", "--views", "4", "--at", "2", "4",
            "--workers", "0", "--quiet", "--out", str(tmp_path)]  # fmt: skip
    assert main([*args, "--replay", str(stored / "old")]) == 0
    out = capsys.readouterr().out
    folder = tmp_path / "3du"
    table = (folder / "3du_table.md").read_text()
    assert table.startswith("| method | runs | after 2 views | after 4 views | mean planning time (s) |")
    assert "| method | runs | coverage after 2 views | coverage after 4 views | views to 80 % |" in table
    assert table.strip() in out
    for name in ("3du_summary.csv", "3du_views_to_coverage.csv", "3du_coverage_runs.csv", "3du_comparison.png",
                 "3du_coverage.png"):  # fmt: skip
        assert (folder / name).is_file() and str(folder / name) in out
    # the stored runs from before the column: read back, the table says so
    assert main([*args[:-1], str(stored / "old")]) == 0
    assert "n/a (run CSV predates the column)" in (stored / "old" / "3du" / "3du_table.md").read_text()
    assert not (stored / "old" / "3du" / "3du_coverage.png").exists()
