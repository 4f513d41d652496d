"""call_with_resend without ROS: a stand-in client that loses the first requests."""

from __future__ import annotations

import pytest

from nbv_prob_cnn.ros.graph import call_with_resend


class Future:
    def __init__(self, answer=None) -> None:
        self.answer = answer

    def done(self) -> bool:
        return self.answer is not None

    def result(self):
        return self.answer


class LossyClient:
    """Answers ``request * 2``, but loses the first ``lost`` requests (their futures never finish)."""

    srv_name = "/double"

    def __init__(self, lost: int, available: bool = True) -> None:
        self.lost, self.available = lost, available
        self.sent: list[int] = []
        self.removed: list[Future] = []

    def wait_for_service(self, timeout_sec: float) -> bool:
        return self.available

    def call_async(self, request: int) -> Future:
        self.sent.append(request)
        return Future(None if len(self.sent) <= self.lost else request * 2)

    def remove_pending_request(self, future: Future) -> None:
        self.removed.append(future)


def test_an_answered_request_is_sent_once():
    client = LossyClient(lost=0)
    assert call_with_resend(client, 21, 5.0, resend_s=0.05) == 42
    assert client.sent == [21] and client.removed == []


def test_lost_requests_are_sent_again_and_forgotten():
    client = LossyClient(lost=2)
    assert call_with_resend(client, 5, 5.0, resend_s=0.05) == 10
    assert client.sent == [5, 5, 5]
    assert len(client.removed) == 2  # the two unanswered requests no longer wait for a reply


class SpinningExecutor:
    def __init__(self) -> None:
        self.spun: list[float] = []

    def spin_until_future_complete(self, future: Future, timeout_sec: float) -> None:
        self.spun.append(timeout_sec)


class SlowClient(LossyClient):
    """Answers each request ``late`` calls after it was sent (a server slower than resend_s)."""

    def __init__(self, late: int) -> None:
        super().__init__(lost=0)
        self.late, self.futures = late, []

    def call_async(self, request: int) -> Future:
        self.sent.append(request)
        self.futures.append(Future())
        if len(self.futures) > self.late:
            self.futures[-1 - self.late].answer = request * 2  # the oldest unanswered one is answered now
        return self.futures[-1]


def test_the_late_answer_to_an_earlier_request_is_taken():
    client = SlowClient(late=2)
    assert call_with_resend(client, 4, 5.0, resend_s=0.05) == 8
    assert client.sent == [4, 4, 4]  # answered at the third send: request 1's answer, not request 3's
    assert client.removed == client.futures[1:]  # the two copies still waiting are forgotten


def test_an_executor_is_spun_for_at_most_resend_s_per_request():
    client, executor = LossyClient(lost=1), SpinningExecutor()
    assert call_with_resend(client, 1, 5.0, executor=executor, resend_s=0.5) == 2
    assert executor.spun == [0.5, 0.5]


def test_no_answer_and_no_service_raise_timeout_errors():
    client = LossyClient(lost=10**6)
    with pytest.raises(TimeoutError, match=r"/double: no answer within 0.3 s \(\d+ request\(s\) sent\)"):
        call_with_resend(client, 1, 0.3, resend_s=0.1)
    assert 2 <= len(client.sent) <= 4
    with pytest.raises(TimeoutError, match="did not appear"):
        call_with_resend(LossyClient(lost=0, available=False), 1, 0.3)
