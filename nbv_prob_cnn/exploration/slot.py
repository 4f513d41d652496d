"""One exploration at a time (no ROS here): the slot an action server's goal claims when it is
accepted, holds while it runs and frees when it ends, and the goal's cancel wired to its
exploration's interrupt, also when the cancel comes between acceptance and execution."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from nbv_prob_cnn.basics.interrupt import Interrupt
from nbv_prob_cnn.exploration.session import CANCELED

#: An accepted goal that never reached execution (its acceptance failed in the middleware) frees
#: the slot after this long (s).
GOAL_CLAIM_S = 10.0


class ExplorationSlot:
    """The slot; goals are any objects (compared by identity).

    Args:
        claim_s: how long an accepted goal holds the slot before it starts (:data:`GOAL_CLAIM_S`).
        clock: monotonic seconds.
    """

    def __init__(self, claim_s: float = GOAL_CLAIM_S, clock: Callable[[], float] = time.monotonic) -> None:
        self.claim_s, self._clock = claim_s, clock
        self._lock = threading.Lock()  # guards the four fields below
        self._active: object | None = None  # the running exploration's goal
        self._interrupt: Interrupt | None = None  # its interrupt
        self._accepted_at: float | None = None  # a goal accepted, not yet running
        self._canceled_before_start: object | None = None  # an accepted goal whose cancel came first

    def claim(self) -> bool:
        """Accept a goal: True when no exploration runs and none was accepted within ``claim_s``."""
        with self._lock:
            now = self._clock()
            claimed = self._accepted_at is not None and now - self._accepted_at < self.claim_s
            if self._active is not None or claimed:
                return False
            self._accepted_at = now
            return True

    def start(self, goal: object, interrupt: Interrupt) -> None:
        """``goal`` runs with ``interrupt`` (triggered at once when its cancel came before)."""
        with self._lock:
            self._active, self._interrupt, self._accepted_at = goal, interrupt, None
            if self._canceled_before_start is goal:
                interrupt.trigger(CANCELED)
            self._canceled_before_start = None

    def cancel(self, goal: object) -> None:
        """A cancel request of ``goal``: its running exploration's interrupt is triggered, or the
        cancel waits for :meth:`start`."""
        with self._lock:
            interrupt = self._interrupt if goal is self._active else None
            if interrupt is None:
                self._canceled_before_start = goal
        if interrupt is not None:
            interrupt.trigger(CANCELED)

    def finish(self) -> None:
        """The running exploration ended: the slot is free."""
        with self._lock:
            self._active = self._interrupt = None
