"""The integrator's waiting frames (nbv_prob_cnn.perception.frame_queue), without ROS: hand-worked
cases of which frames wait and which are dropped."""

from __future__ import annotations

from nbv_prob_cnn.perception.frame_queue import FrameQueue
from nbv_prob_cnn.perception.messages import PairedFrame


def frame(stamp: int) -> PairedFrame:
    return PairedFrame(stamp, f"image{stamp}", "info", "pose")


def stamps(queue: FrameQueue) -> list[int]:
    out = []
    while (taken := queue.pop()) is not None:
        out.append(taken.stamp_ns)
    return out


def test_drop_when_behind_keeps_the_newest_frame_only() -> None:
    queue = FrameQueue(drop_when_behind=True)
    assert queue.pop() is None and len(queue) == 0
    assert queue.put(frame(5)) == 0  # nothing waited
    assert queue.put(frame(3)) == 1  # replaces frame 5: the one that arrived last wins, whatever its stamp
    assert queue.put(frame(7)) == 1
    assert len(queue) == 1
    assert stamps(queue) == [7]
    assert queue.put(frame(8)) == 0  # the queue was empty again


def test_without_drop_when_behind_every_frame_waits_in_stamp_order() -> None:
    queue = FrameQueue(drop_when_behind=False)
    for stamp in (5, 3, 9, 5, 1):
        assert queue.put(frame(stamp)) == 0
    assert len(queue) == 5
    first = queue.pop()
    assert first is not None and first.stamp_ns == 1
    assert stamps(queue) == [3, 5, 5, 9]
    # a frame of an equal stamp goes after the one waiting (arrival order among equals)
    a, b = frame(4), frame(4)
    queue.put(a)
    queue.put(b)
    assert queue.pop() is a and queue.pop() is b


def test_backlog_beyond_its_limit_drops_the_oldest() -> None:
    queue = FrameQueue(drop_when_behind=False, max_backlog=3)
    assert [queue.put(frame(s)) for s in (10, 20, 30)] == [0, 0, 0]
    assert queue.put(frame(25)) == 1  # 10, 20, 25, 30 -> 10 dropped
    assert queue.put(frame(5)) == 1  # the late frame is the oldest: dropped itself
    assert stamps(queue) == [20, 25, 30]


def test_clear_says_how_many_frames_it_discarded() -> None:
    queue = FrameQueue(drop_when_behind=False)
    for stamp in (1, 2, 3):
        queue.put(frame(stamp))
    assert queue.clear() == 3 and len(queue) == 0 and queue.clear() == 0
