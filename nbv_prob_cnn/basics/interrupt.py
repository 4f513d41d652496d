"""Waits that end at once when they are interrupted (a goal canceled, a node shutting down):
:class:`Interrupt` and :func:`wait_on`. No ROS here: an rclpy future is waited on through its
``add_done_callback`` and ``done`` alone (a ``concurrent.futures.Future`` works the same)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, Protocol


class Waitable(Protocol):
    """What :meth:`Interrupt.wait_future` needs of a future (rclpy's, ``concurrent.futures``')."""

    def add_done_callback(self, callback: Callable[[Any], object], /) -> Any: ...

    def done(self) -> bool: ...


class WaitInterruptedError(Exception):
    """A wait ended early because its :class:`Interrupt` was triggered (a goal was canceled, the
    node is shutting down); the message is the interrupt's reason."""


class Interrupt:
    """A one-way flag that wakes every wait made through it at once.

    A callback that waits (for a service reply, a grid, the arm's arrival) waits through an
    interrupt: :meth:`wait_for` on a condition, :meth:`wait_future` on a future, or
    :meth:`wait_until` on something that can only be polled. :meth:`trigger` (a goal's cancel
    callback, the node's shutdown in :func:`~nbv_prob_cnn.ros.runtime.run_node`) wakes all of
    them; they raise :class:`WaitInterruptedError`. A :meth:`child` is triggered with its parent
    (a goal's interrupt with the node's).
    """

    def __init__(self, parent: Interrupt | None = None) -> None:
        self._lock = threading.Lock()
        self._reason: str | None = None
        self._wakers: list[Callable[[], None]] = []  # called once when triggered
        self._parent = parent
        if parent is not None and not parent._add_waker(self._follow_parent):
            self._follow_parent()  # the parent was triggered already

    def _follow_parent(self) -> None:
        assert self._parent is not None
        self.trigger(self._parent.reason or "")

    @property
    def reason(self) -> str | None:
        """Why it was triggered; None while it was not."""
        return self._reason

    def is_set(self) -> bool:
        return self._reason is not None

    def trigger(self, reason: str) -> None:
        """Set the flag (the first reason stays) and wake every wait made through it."""
        with self._lock:
            if self._reason is not None:
                return
            self._reason = reason
            wakers, self._wakers = self._wakers, []
        for wake in wakers:
            wake()

    def check(self) -> None:
        """Raise :class:`WaitInterruptedError` when triggered."""
        if self._reason is not None:
            raise WaitInterruptedError(self._reason)

    def child(self) -> Interrupt:
        """An interrupt of its own that this one also triggers (:meth:`release` it when done)."""
        return Interrupt(self)

    def release(self) -> None:
        """A child that is no longer used: its parent stops holding it."""
        if self._parent is not None:
            self._parent._remove_waker(self._follow_parent)

    def _add_waker(self, wake: Callable[[], None]) -> bool:
        """Register ``wake``; False (not registered) when already triggered."""
        with self._lock:
            if self._reason is not None:
                return False
            self._wakers.append(wake)
            return True

    def _remove_waker(self, wake: Callable[[], None]) -> None:
        with self._lock, contextlib.suppress(ValueError):
            self._wakers.remove(wake)

    @contextlib.contextmanager
    def _waking(self, wake: Callable[[], None]) -> Iterator[None]:
        """``wake`` is called if the interrupt is triggered while the block runs."""
        registered = self._add_waker(wake)
        try:
            yield
        finally:
            if registered:
                self._remove_waker(wake)

    def wait_for(self, condition: threading.Condition, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """``condition.wait_for(predicate, timeout_s)`` (call with ``condition`` held) that also
        ends when the interrupt is triggered.

        Returns:
            The predicate's last value (False: timed out).

        Raises:
            WaitInterruptedError: triggered before or while waiting.
        """

        def wake() -> None:
            with condition:
                condition.notify_all()

        with self._waking(wake):
            result = condition.wait_for(lambda: self.is_set() or predicate(), timeout_s)
        self.check()
        return bool(result)

    def wait_future(self, future: Waitable, timeout_s: float) -> bool:
        """Wait until a future (an rclpy one, completed by the executor's other threads) is done.

        Returns:
            Whether it is done (False: timed out).

        Raises:
            WaitInterruptedError: triggered before or while waiting.
        """
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        with self._waking(done.set):
            done.wait(timeout_s)
        self.check()
        return bool(future.done())

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float, period_s: float = 0.05) -> bool:
        """Poll ``predicate`` every ``period_s`` until it holds or ``timeout_s`` passes (for what
        has no notification: a service or action server becoming available).

        Raises:
            WaitInterruptedError: triggered before or while waiting.
        """
        woken = threading.Event()
        deadline = time.monotonic() + timeout_s
        with self._waking(woken.set):
            while True:
                self.check()
                if predicate():
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                woken.wait(min(period_s, remaining))


def wait_on(
    condition: threading.Condition, predicate: Callable[[], bool], timeout_s: float, interrupt: Interrupt | None
) -> bool:
    """``condition.wait_for`` (``condition`` held), through ``interrupt`` when there is one."""
    if interrupt is None:
        return condition.wait_for(predicate, timeout_s)
    return interrupt.wait_for(condition, predicate, timeout_s)
