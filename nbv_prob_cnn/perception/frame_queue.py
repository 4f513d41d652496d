"""The paired depth frames waiting for integration, and which of them are dropped when
integration falls behind (the ``integrator``'s ``drop_when_behind``).

When integration falls behind, ``drop_when_behind`` (default) keeps only the newest waiting frame;
with ``drop_when_behind:=false`` every paired frame is integrated in stamp order (deterministic: a
bag replayed this way gives the same grid as ``nbv integrate`` on the bag, provided the
subscriptions lose nothing either: use ``qos_reliability:=reliable`` (the default is SENSOR_DATA:
best effort, ``queue_size`` 5), and reliable QoS keeps only the newest ``queue_size`` messages per
topic that the node has not taken yet, so a replay much faster than real time needs ``queue_size``
at least the burst). At most :data:`MAX_BACKLOG` frames wait then; beyond that the oldest are dropped.
"""

from __future__ import annotations

import bisect
from collections import deque

from nbv_prob_cnn.perception.messages import PairedFrame

#: Most frames waiting for integration with ``drop_when_behind:=false`` (older ones are dropped beyond it).
MAX_BACKLOG = 1000


class FrameQueue:
    """Frames waiting for integration, oldest first: the newest one alone with ``drop_when_behind``,
    else all of them in stamp order (at most ``max_backlog``). Not thread-safe (the node calls it
    under its lock)."""

    def __init__(self, drop_when_behind: bool, max_backlog: int = MAX_BACKLOG) -> None:
        self.drop_when_behind = drop_when_behind
        self.max_backlog = max_backlog
        self._frames: deque[PairedFrame] = deque()

    def __len__(self) -> int:
        return len(self._frames)

    def put(self, frame: PairedFrame) -> int:
        """Add ``frame`` (after the waiting frames of the same or an older stamp); the number of
        waiting frames dropped for it (the one waiting with ``drop_when_behind``, else the oldest
        beyond ``max_backlog``)."""
        if self.drop_when_behind:
            dropped = len(self._frames)
            self._frames.clear()
            self._frames.append(frame)
            return dropped
        index = bisect.bisect_right([f.stamp_ns for f in self._frames], frame.stamp_ns)
        self._frames.insert(index, frame)
        dropped = 0
        while len(self._frames) > self.max_backlog:
            self._frames.popleft()
            dropped += 1
        return dropped

    def pop(self) -> PairedFrame | None:
        """The oldest waiting frame, taken out; None when none waits."""
        return self._frames.popleft() if self._frames else None

    def clear(self) -> int:
        """Discard every waiting frame; how many there were."""
        discarded = len(self._frames)
        self._frames.clear()
        return discarded
