"""The files of an exploration (``explore_client.write_outputs``) count views as the console does: 1 for
the first (issue 48: the console said 1-3, views.csv and the plot 0-2, the plot with fractional ticks)."""

from __future__ import annotations

import csv

import numpy as np
from matplotlib.figure import Figure
from nbv_prob_cnn_msgs.action import Explore

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.ros.conversions import grid_to_msg
from nbv_prob_cnn.ros.explore_client import write_outputs


class RecordedClient:
    """What write_outputs reads of an ExploreClient: the feedback of a finished run and the last grid."""

    def __init__(self, feedback, grid, surface_coverage=None):
        self.feedback, self._grid = feedback, grid
        self.surface_coverage = surface_coverage or {}

    def latest_grid(self):
        return self._grid


def test_views_count_from_one_in_the_csv_and_the_plot(tmp_path, monkeypatch):
    state = np.full((8, 8, 8), -1, np.int8)
    state[2:6, 2:6, 2:6] = 0
    geometry = GridGeometry((0.0, 0.0, 0.0), 0.1, state.shape)
    feedback, result = [], Explore.Result()
    for index in range(3):
        fb = Explore.Feedback(
            view_index=index, executed=True, gain=0.5 - 0.1 * index, unknown_fraction=0.9 - 0.1 * index
        )
        fb.pose.pose.position.x = fb.pose.pose.position.y = fb.pose.pose.position.z = 0.35
        fb.pose.pose.orientation.w = 1.0
        feedback.append((1.0 + index, fb))
        result.poses.append(fb.pose)
    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: figures.append(fig))
    write_outputs(RecordedClient(feedback, grid_to_msg(state, geometry)), result, tmp_path, "run")
    with open(tmp_path / "views.csv", newline="") as handle:
        assert [int(row["view"]) for row in csv.DictReader(handle)] == [1, 2, 3]
    (fig,) = figures
    curve = fig.axes[-1]
    assert curve.get_xlabel() == "view"
    np.testing.assert_array_equal(curve.lines[0].get_xdata(), [1, 2, 3])
    ticks = [t for t in curve.get_xticks() if curve.get_xlim()[0] <= t <= curve.get_xlim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks


def test_views_csv_keeps_the_surface_coverage_where_measured(tmp_path, monkeypatch):
    """The client's per-view coverage (by view_index) lands in its view's row; a view without one
    (no world known, as on a real robot) leaves the cell empty."""
    state = np.full((8, 8, 8), -1, np.int8)
    geometry = GridGeometry((0.0, 0.0, 0.0), 0.1, state.shape)
    feedback, result = [], Explore.Result()
    for index in range(3):
        fb = Explore.Feedback(view_index=index, executed=True, gain=0.5, unknown_fraction=0.5)
        fb.pose.pose.position.x = fb.pose.pose.position.y = fb.pose.pose.position.z = 0.35
        fb.pose.pose.orientation.w = 1.0
        feedback.append((1.0 + index, fb))
        result.poses.append(fb.pose)
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: None)
    client = RecordedClient(feedback, grid_to_msg(state, geometry), {0: 0.25, 2: 0.5})
    write_outputs(client, result, tmp_path, "run")
    with open(tmp_path / "views.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["surface_coverage"] for r in rows] == ["0.250000", "", "0.500000"]
