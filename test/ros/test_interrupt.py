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
    parent = Interrupt()
    child = parent.child()
    future = Future()
    threading.Thread(target=lambda: (time.sleep(0.05), future.set_result(7))).start()
    assert child.wait_future(future, LONG_S) and future.result() == 7
    assert not child.wait_future(Future(), 0.05)

    trigger = threading.Timer(0.1, parent.trigger, ("nbv_planner is shutting down",))
    trigger.start()
    start = time.monotonic()
    with pytest.raises(WaitInterruptedError, match="nbv_planner is shutting down"):
        child.wait_future(Future(), LONG_S)
    assert time.monotonic() - start < 5.0
    trigger.join()
    assert child.reason == "nbv_planner is shutting down"
