"""``nbv study restart_soak`` (issue 47): which plans and explorations must have succeeded (those that
overlap no server's down time), on hand-made events (no ROS)."""

from __future__ import annotations

import pytest

from studies.restart_soak import Restart, down_spans, judge, main, outcome, overlaps_down


def test_a_server_is_down_from_its_stop_to_its_ready_or_to_the_end():
    restarts = [Restart("gain_server", "SIGKILL", 10.0, 14.0), Restart("completion_server", "SIGINT", 40.0, None)]
    assert down_spans(restarts, 100.0) == [(10.0, 14.0), (40.0, 100.0)]


@pytest.mark.parametrize(
    ("start", "end", "expected"),
    [
        (0.0, 9.9, False),  # ended before the stop
        (14.1, 30.0, False),  # asked after the ready: must succeed
        (9.0, 11.0, True),  # the stop came while it ran
        (13.0, 20.0, True),  # started while down
        (8.0, 16.0, True),  # spans the whole down time
        (14.0, 15.0, True),  # at the ready itself (closed spans)
    ],
)
def test_overlap_with_a_down_time(start, end, expected):
    assert overlaps_down(start, end, [(10.0, 14.0)]) is expected


def test_outcomes_tell_server_failures_from_the_planners_refusals():
    assert outcome(True, "") == "ok"
    assert outcome(False, "service /nbv/complete did not answer within 10.0 s") == "failed"
    assert outcome(False, "service /nbv/rank_views: no answer within 10 s (2 request(s) sent)") == "failed"
    assert outcome(False, "no answer within 30 s") == "failed"  # the plan client's own wait
    assert outcome(False, "no grid received yet on /nbv/grid") == "refused"
    assert outcome(False, "no view with positive gain: the grid has no empty cell") == "refused"


def test_judge_counts_by_overlap_and_outcome():
    events = [
        {"start_wall": 1.0, "end_wall": 2.0, "outcome": "ok"},
        {"start_wall": 3.0, "end_wall": 4.0, "outcome": "failed"},  # up, failed: a violation
        {"start_wall": 5.0, "end_wall": 6.0, "outcome": "refused"},
        {"start_wall": 9.0, "end_wall": 12.0, "outcome": "failed"},  # down, failed: expected
        {"start_wall": 12.0, "end_wall": 15.0, "outcome": "ok"},  # down, but answered
    ]
    counts = judge(events, [(10.0, 14.0)])
    assert counts == {"up_ok": 1, "up_refused": 1, "up_failed": 1, "down_ok": 1, "down_refused": 0, "down_failed": 1}


def test_bad_periods_are_refused(capsys):
    with pytest.raises(ValueError, match="--restart-period"):
        main(["--minutes", "1", "--restart-period", "0"])
