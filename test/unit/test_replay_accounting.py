"""The closing account of a bag replay (issue 18): counts of two integrator reports, hand-worked."""

from __future__ import annotations

import pytest

from nbv_prob_cnn.perception.replay_accounting import replay_delta, replay_line


def report(images: int, integrated: int, pending: int = 0, **dropped: int) -> dict:
    return {
        "images": images,
        "integrated": integrated,
        "pending": pending,
        "dropped": {"behind": 0, "no_pose": 0, "reset": 0, **dropped},
        "lost_in_transport": {"camera/depth/image": 0},
    }


def test_delta_counts_only_this_replay() -> None:
    before = report(10, 7, behind=3)  # an earlier live session: 3 dropped as behind
    after = report(40, 35, pending=0, behind=4, no_pose=1)
    delta = replay_delta(before, after)
    assert (delta.received, delta.integrated, delta.pending) == (30, 28, 0)
    assert delta.dropped == {"behind": 1, "no_pose": 1}
    assert replay_line(30, delta) == "sent 30, integrated 28, dropped 2 by reason (behind 1, no_pose 1); received 30"


def test_frames_never_received_are_named() -> None:
    before = {"images": 0, "integrated": 0, "dropped": {}, "lost_in_transport": {"camera/depth/image": 0}}
    after = {"images": 26, "integrated": 26, "pending": 0, "dropped": {}}
    after["lost_in_transport"] = {"camera/depth/image": 1}
    line = replay_line(30, replay_delta(before, after))
    assert line == (
        "sent 30, integrated 26, dropped 0 by reason (none); received 26; "
        "4 sent but never received (lost in transport: camera/depth/image 1)"
    )


def test_no_diagnostics_says_so() -> None:
    expected = "sent 5 frame(s); integrated and dropped unknown (no integrator diagnostics answered)"
    assert replay_line(5, None) == expected


def test_a_restarted_integrator_is_an_error() -> None:
    with pytest.raises(ValueError, match="images went down from 10 to 2"):
        replay_delta(report(10, 10), report(2, 2))
    with pytest.raises(ValueError, match="not an integrator diagnostics report"):
        replay_delta({"images": 1}, report(2, 2))
