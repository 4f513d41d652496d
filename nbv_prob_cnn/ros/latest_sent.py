"""What a latched-like topic last sent (no ROS here): the integrator sends its latest grid (compressed)
and its occupied-cells cloud only while someone subscribes, when the item is new, or again when a
subscriber joined since (a volatile subscriber that comes later, such as RViz, gets the current item
without waiting for the next one)."""

from __future__ import annotations

from typing import Any


class LatestSent:
    """The item last sent on a topic (by identity) and the subscriber count then."""

    def __init__(self) -> None:
        self._item: Any = None
        self._subscribers = 0

    def due(self, item: Any, subscribers: int) -> bool:
        """Whether ``item`` (None: nothing to send) should go out to the ``subscribers`` there are now:
        someone listens, and ``item`` is not the one last sent or more subscribers listen than then.
        Someone leaving lowers the count kept, so the next one to join is new."""
        if item is None or subscribers == 0:
            self._subscribers = 0  # whoever subscribes next is new
            return False
        if item is self._item and subscribers <= self._subscribers:
            self._subscribers = subscribers  # sent already (someone left: fewer now)
            return False
        return True

    def sent(self, item: Any, subscribers: int) -> None:
        """Record that ``item`` went out to ``subscribers``."""
        self._item, self._subscribers = item, subscribers
