"""The stop rule's trade-off from runs to the budget (studies/surface_stop.py), worked by hand."""

from __future__ import annotations

import math

import pytest

from studies.surface_blend import views_to
from studies.surface_stop import analyse, stop_view

NAN = float("nan")


def test_the_rule_stops_before_the_first_view_below_the_threshold():
    estimates = [NAN, 400.0, 120.0, 30.0, 80.0, 4.0]
    assert stop_view(estimates, 50.0) == 3  # views 0, 1, 2 taken; the view of 30 cells is not
    assert stop_view(estimates, 5.0) == 5
    assert stop_view(estimates, 1.0) is None  # never below: the run goes to its budget


def test_views_saved_and_coverage_lost_by_hand():
    runs = [
        ([NAN, 400.0, 120.0, 30.0, 80.0, 4.0], [0.1, 0.5, 0.8, 0.9, 0.95, 0.96]),
        ([NAN, 300.0, 10.0, 2.0, 1.0, 1.0], [0.2, 0.7, 0.9, 0.91, 0.91, 0.92]),
    ]
    row = analyse(runs, [50.0])[0]
    # run 1 stops with 3 views (coverage 0.8, lost 0.16); run 2 with 2 views (0.7, lost 0.22)
    assert row.stopped == 2 and row.mean_views == 2.5 and row.views_saved == 3.5
    assert row.coverage_lost_mean == pytest.approx(0.19) and row.coverage_lost_max == pytest.approx(0.22)
    row = analyse(runs, [0.5])[0]  # below every estimate: no run stops, nothing lost
    assert row.stopped == 0 and row.mean_views == 6 and row.coverage_lost_max == 0.0


def test_views_to_a_level_counts_the_views_taken():
    import numpy as np

    assert views_to(np.array([0.1, 0.85, 0.96]), 0.95) == 3.0 and views_to(np.array([0.1, 0.85]), 0.8) == 2.0
    assert math.isnan(views_to(np.array([0.1, 0.5]), 0.95))


def test_estimates_after_the_first_below_every_threshold_change_nothing():
    """The replay stops estimating once an estimate is below the smallest threshold: every threshold
    has stopped the run by then, so NaN in their place gives the same rows."""
    coverage = [0.1, 0.5, 0.8, 0.9, 0.95, 0.96]
    full = [NAN, 400.0, 120.0, 3.0, 80.0, 1.0]
    cut = [NAN, 400.0, 120.0, 3.0, NAN, NAN]
    thresholds = [5.0, 50.0, 200.0]
    assert analyse([(cut, coverage)], thresholds) == analyse([(full, coverage)], thresholds)


def test_run_paths_tell_the_guarded_runs_apart(tmp_path):
    from studies.surface_stop import run_paths

    for name in ("3du_cnn_surface_seed121", "3du_cnn_surface_seed120", "3du_cnn_surface_guarded_seed120"):
        (tmp_path / f"{name}.csv").write_text("")
    plain = ["3du_cnn_surface_seed120", "3du_cnn_surface_seed121"]
    assert [p.stem for p in run_paths(tmp_path, "cnn_surface")] == plain
    assert [p.stem for p in run_paths(tmp_path, "cnn_surface", guarded=True)] == ["3du_cnn_surface_guarded_seed120"]
