"""A plan that falls back near the camera ranks and checks twice: what the user sees (the plan
response's times and ``arm_checked``, the view's log line) counts both passes and says what the
first found (issue 46's review). Hand-made reports, sums worked by hand; no ROS."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.arm.arm_session import unreachable_message
from nbv_prob_cnn.arm.feasibility import ArmView, FeasibilityReport
from nbv_prob_cnn.exploration.step_log import fallback_note
from nbv_prob_cnn.planners import ViewChoice
from nbv_prob_cnn.planners.recording import RecordingPlanner


def first_pass() -> FeasibilityReport:
    """The first pass of the robot example's fallback plan: 300 in collision, 673 camera-blocked."""
    return FeasibilityReport(
        view=None, ranked=1000, candidates=980, camera_blocked=673, checked=300, in_collision=300,
        budget_exhausted=True, times={"capability": 0.25, "ik_collision": 4.5, "gain": 1.0},
        parts={"ik": 2.5, "collision": 1.75},
    )  # fmt: skip


def near_pass(first: FeasibilityReport | None) -> FeasibilityReport:
    """The pass near the camera: 3 checked (1 unreachable, 1 in collision, the third taken by a planned path)."""
    view = ArmView(ViewChoice(np.array([1, 2, 3]), 4, 0.5), np.zeros(9), 1.5, 0.5)
    return FeasibilityReport(
        view=view, ranked=40, candidates=30, camera_blocked=2, checked=3, unreachable=1, in_collision=1,
        fallback=first is not None, first_pass=first, paths_planned=1,
        times={"capability": 0.125, "ik_collision": 0.5, "gain": 0.75, "path_planning": 0.25},
        parts={"ik": 0.25, "collision": 0.125, "alternatives": 0.0625}, path_stages={"solve": 0.25},
        path_length_rad=1.5,
    )  # fmt: skip


def test_the_total_of_a_fallback_sums_both_passes_by_hand():
    near = near_pass(first_pass())
    total = near.total()
    assert total.view is near.view and total.fallback and total.first_pass is None
    counts = ("ranked", "candidates", "camera_blocked", "checked", "unreachable", "in_collision", "path_blocked")
    # 1000 + 40, 980 + 30, 673 + 2, 300 + 3, 0 + 1, 300 + 1, 0 + 0
    assert [getattr(total, name) for name in counts] == [1040, 1010, 675, 303, 1, 301, 0]
    assert (total.paths_planned, total.paths_not_found) == (1, 0)
    assert total.budget_exhausted  # the first pass spent it
    # capability 0.25 + 0.125, IK+collision 4.5 + 0.5, gain 1.0 + 0.75, path planning 0 + 0.25
    assert total.times == pytest.approx({"capability": 0.375, "ik_collision": 5.0, "gain": 1.75, "path_planning": 0.25})
    assert total.parts == pytest.approx({"ik": 2.75, "collision": 1.875, "alternatives": 0.0625})
    assert total.path_stages == pytest.approx({"solve": 0.25})
    assert total.path_length_rad == pytest.approx(1.5)
    # the passes themselves are left as they were (the arm check's log line shows each)
    assert near.checked == 3 and near.times["ik_collision"] == 0.5 and near.first_pass.checked == 300


def test_without_a_fallback_the_total_is_the_report_itself():
    near = near_pass(None)
    assert near.total() is near
    assert near.fallback_text() == ""
    assert fallback_note(False, "") == ""


def test_the_fallback_text_says_what_the_first_pass_found():
    near = near_pass(first_pass())
    assert near.fallback_text() == (
        "fallback after 300 checked: 300 in collision, 673 camera-blocked skipped, check budget spent"
    )
    assert fallback_note(True, near.fallback_text()) == (
        " (fallback after 300 checked: 300 in collision, 673 camera-blocked skipped, check budget spent)"
    )
    # the view line's note ends at its first ")" (studies/robot_plans.py reads it so)
    assert ")" not in near.fallback_text() and "(" not in near.fallback_text()
    unreachable = FeasibilityReport(view=None, ranked=5, candidates=5, checked=5, unreachable=5)
    assert near_pass(unreachable).fallback_text() == "fallback after 5 checked: 5 unreachable"
    mixed = FeasibilityReport(view=None, ranked=9, candidates=9, checked=9, unreachable=2, in_collision=3,
                              path_blocked=4)  # fmt: skip
    assert near_pass(mixed).fallback_text() == (
        "fallback after 9 checked: 2 unreachable, 3 in collision, 4 path blocked"
    )
    nothing = FeasibilityReport(view=None, ranked=12, candidates=0)  # the capability map kept none
    assert near_pass(nothing).fallback_text() == "fallback after 0 checked: 12 ranked, 0 candidates"
    # a response without the text (an older planner) still says it fell back
    assert fallback_note(True, "") == " (fallback: no ranked view was feasible)"


def test_no_view_even_near_the_camera_counts_both_passes():
    near = FeasibilityReport(view=None, ranked=40, candidates=30, checked=4, unreachable=1, in_collision=2,
                             path_blocked=1, fallback=True, first_pass=first_pass())  # fmt: skip
    # 300 + 4 checked, 0 + 1 unreachable, 300 + 2 in collision, 0 + 1 path blocked
    assert unreachable_message(near) == (
        "no view the arm reaches collision-free: 304 ranked views checked (1 without IK solution, 302 in collision, "
        "1 with a blocked path, check budget spent, near the camera too)"
    )


class _TimedRanks:
    """A planner whose ranks return one view with the given stage times, in turn."""

    name = "timed"

    def __init__(self, times: list[dict[str, float]]) -> None:
        self.times = list(times)

    def rank(self, state, context, top_k=1, origin_filter=None):
        times = self.times.pop(0)
        return [ViewChoice(np.array([0, 0, 0]), 0, 1.0, times=times)] if times else []


def test_the_recording_planner_sums_the_stage_times_of_every_rank():
    first = {"cnn": 0.5, "raycast": 0.25, "views": 0.125}
    near = {"cnn": 0.0625, "raycast": 0.03125, "views": 0.015625}
    planner = RecordingPlanner(_TimedRanks([first, {}, near]), lambda origins: origins)
    for _ in range(3):  # the second rank finds nothing: its time still counts, it has no stages
        planner.rank(np.zeros((2, 2, 2), np.int8), None, 1)
    seconds = planner.stage_seconds
    assert seconds["cnn"] == pytest.approx(0.5625)  # 0.5 + 0.0625
    assert seconds["raycast"] == pytest.approx(0.28125)  # 0.25 + 0.03125
    assert seconds["views"] == pytest.approx(0.140625)  # 0.125 + 0.015625
    assert seconds["rank"] >= planner.seconds >= 0.0  # the three calls' own time, the last one's among them
    assert planner.ranked[0].times["cnn"] == 0.0625  # the last rank's list, as before
