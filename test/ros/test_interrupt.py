"""``basics.interrupt.Interrupt`` on an rclpy future: the wait returns once the future is done, times
out, and ends at once (not at its timeout) when the interrupt's parent is triggered from another
thread. The waits without rclpy are tested in test/unit/test_interrupt_waits.py."""

from __future__ import annotations

import threading
import time

import pytest

pytest.importorskip("rclpy")

from rclpy.task import Future  # noqa: E402

from nbv_prob_cnn.basics.interrupt import Interrupt, WaitInterruptedError  # noqa: E402

LONG_S = 30.0  # a timeout no test may wait out


def test_an_rclpy_future_wait_returns_times_out_or_ends_on_a_parent_trigger() -> None:
    parent, answered, unanswered = Interrupt(), Future(), Future()
    threading.Timer(0.05, answered.set_result, (7,)).start()  # as an executor thread completes it
    assert parent.child().wait_future(answered, LONG_S) and answered.result() == 7
    assert not parent.child().wait_future(unanswered, 0.05)  # a plain timeout

    waiting = parent.child()
    trigger = threading.Timer(0.1, parent.trigger, ("nbv_planner is shutting down",))
    trigger.start()
    start = time.monotonic()
    with pytest.raises(WaitInterruptedError, match="nbv_planner is shutting down"):
        waiting.wait_future(unanswered, LONG_S)
    assert time.monotonic() - start < 5.0 and not unanswered.done()
    trigger.join()
