"""``basics.interrupt.Interrupt``, the one waiting helper of the nodes (no ROS): each kind of wait
returns its own result when not interrupted, and ends at once (not at its timeout) when the
interrupt, or its parent, is triggered from another thread. ``wait_future`` takes any future with
``add_done_callback`` and ``done`` (here ``concurrent.futures``'; rclpy's in test/ros/test_interrupt.py)."""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future

from nbv_prob_cnn.basics.interrupt import Interrupt, WaitInterruptedError, wait_on

LONG_S = 30.0  # a timeout no test may wait out


def trigger_later(interrupt: Interrupt, reason: str, delay_s: float = 0.1) -> threading.Thread:
    thread = threading.Thread(target=lambda: (time.sleep(delay_s), interrupt.trigger(reason)))
    thread.start()
    return thread


def ended_within(call, seconds: float) -> BaseException | None:
    """Run ``call``; return what it raised, asserting it ended within ``seconds``."""
    start = time.monotonic()
    try:
        call()
    except Exception as exc:  # the caller checks what was raised
        raised: BaseException | None = exc
    else:
        raised = None
    assert time.monotonic() - start < seconds
    return raised


def test_condition_wait_returns_the_predicate_or_ends_on_trigger() -> None:
    interrupt, condition, state = Interrupt(), threading.Condition(), {"ready": False}

    def set_ready() -> None:
        time.sleep(0.05)
        with condition:
            state["ready"] = True
            condition.notify_all()

    threading.Thread(target=set_ready).start()
    with condition:
        assert interrupt.wait_for(condition, lambda: state["ready"], LONG_S)
    with condition:
        assert not interrupt.wait_for(condition, lambda: False, 0.05)  # a plain timeout
    with condition:
        assert not wait_on(condition, lambda: False, 0.05, None)  # no interrupt: the plain wait

    thread = trigger_later(interrupt, "goal canceled")
    with condition:
        raised = ended_within(lambda: interrupt.wait_for(condition, lambda: False, LONG_S), 5.0)
    thread.join()
    assert isinstance(raised, WaitInterruptedError) and str(raised) == "goal canceled"
    with condition:  # once triggered, every later wait ends at once
        assert isinstance(ended_within(lambda: wait_on(condition, lambda: True, LONG_S, interrupt), 1.0),
                          WaitInterruptedError)  # fmt: skip


def test_future_and_polled_waits_end_on_a_parent_trigger() -> None:
    parent = Interrupt()
    child = parent.child()
    future = Future()
    threading.Thread(target=lambda: (time.sleep(0.05), future.set_result(7))).start()
    assert child.wait_future(future, LONG_S) and future.result() == 7
    assert not child.wait_future(Future(), 0.05)
    assert child.wait_until(lambda: True, LONG_S)
    assert not child.wait_until(lambda: False, 0.1)

    thread = trigger_later(parent, "nbv_planner is shutting down")
    raised = ended_within(lambda: child.wait_future(Future(), LONG_S), 5.0)
    thread.join()
    assert isinstance(raised, WaitInterruptedError) and child.reason == "nbv_planner is shutting down"
    assert isinstance(ended_within(lambda: child.wait_until(lambda: False, LONG_S), 1.0), WaitInterruptedError)

    # a released child no longer follows its parent; a child of a triggered parent starts triggered
    other_parent = Interrupt()
    released = other_parent.child()
    released.release()
    other_parent.trigger("later")
    assert not released.is_set() and other_parent.child().reason == "later"


def test_the_interrupt_module_imports_no_rclpy() -> None:
    import subprocess
    import sys

    code = "import sys, nbv_prob_cnn.basics.interrupt; print('rclpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
