"""One exploration at a time (ExplorationSlot) and the camera workspace of a plan, without ROS."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.session import CANCELED
from nbv_prob_cnn.exploration.slot import ExplorationSlot
from nbv_prob_cnn.planners.workspace import UNBOUNDED, height_box, intersect_boxes, workspace_box


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_one_goal_at_a_time_and_a_claim_that_never_started_expires():
    clock = Clock()
    slot = ExplorationSlot(claim_s=10.0, clock=clock)
    assert slot.claim() and not slot.claim()  # accepted, not yet running: the slot is held
    clock.now += 9.9
    assert not slot.claim()
    clock.now += 0.2  # 10.1 s after the claim that never started
    assert slot.claim()
    slot.start("goal A", Interrupt())
    clock.now += 100.0
    assert not slot.claim()  # running: held however long it runs
    slot.finish()
    assert slot.claim()


def test_a_cancel_triggers_the_running_goals_interrupt_only():
    slot = ExplorationSlot()
    running = Interrupt()
    slot.start("goal A", running)
    slot.cancel("goal B")  # not the running goal: kept until B starts
    assert not running.is_set()
    slot.cancel("goal A")
    assert running.reason == CANCELED
    slot.finish()
    later = Interrupt()
    slot.start("goal B", later)  # its cancel came before it started
    assert later.reason == CANCELED
    slot.finish()
    again = Interrupt()
    slot.start("goal B", again)  # a cancel counts once
    assert not again.is_set()


def test_workspace_box_and_its_errors():
    assert workspace_box([], []) is None
    low, high = workspace_box([0, 0.5, 0], [1, 1, 2])
    np.testing.assert_array_equal(low, [0, 0.5, 0])
    np.testing.assert_array_equal(high, [1, 1, 2])
    with pytest.raises(ValueError, match="3 finite numbers"):
        workspace_box([0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="3 finite numbers"):
        workspace_box([0, 0, float("nan")], [1, 1, 1])
    with pytest.raises(ValueError, match="exceeds workspace_max"):
        workspace_box([0, 2, 0], [1, 1, 1])


def test_the_planning_box_intersects_the_boxes_given():
    assert height_box(0.0, 0.0) is None and intersect_boxes(None, None) is None
    heights = height_box(0.2, 0.0)  # a lowest camera height only
    assert heights is not None
    np.testing.assert_array_equal(heights[0], [-UNBOUNDED, -UNBOUNDED, 0.2])
    np.testing.assert_array_equal(heights[1], [UNBOUNDED, UNBOUNDED, UNBOUNDED])
    box = intersect_boxes((np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0])), None, heights,
                          (np.array([0.5, -1.0, 0.1]), np.array([2.0, 0.8, 0.9])))  # fmt: skip
    assert box is not None
    np.testing.assert_array_equal(box[0], [0.5, 0.0, 0.2])
    np.testing.assert_array_equal(box[1], [1.0, 0.8, 0.9])
