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

    def service_is_ready(self) -> bool:
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


def test_a_server_that_appears_after_the_send_gets_a_copy_at_once():
    """Issue 47: the first request went to the servers known then (a killed one among them); the
    restarted server, seen only afterwards, gets a copy without waiting ``resend_s``."""
    client = LossyClient(lost=1)

    def servers() -> set:
        return {b"old"} if not client.sent else {b"old", b"restarted"}

    assert call_with_resend(client, 3, 30.0, resend_s=1000.0, servers=servers) == 6
    assert client.sent == [3, 3] and len(client.removed) == 1


def test_a_wait_that_raises_ends_the_call_and_forgets_its_requests():
    client = LossyClient(lost=10**6)
    calls: list[float] = []

    def wait(predicate, seconds: float) -> bool:
        calls.append(seconds)
        if len(calls) > 1:  # the first wait is for the service
            raise InterruptedError("shutting down")
        return predicate()

    with pytest.raises(InterruptedError):
        call_with_resend(client, 1, 30.0, resend_s=5.0, wait=wait)
    assert calls == [30.0, 5.0] and client.sent == [1]
    assert len(client.removed) == 1


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


class GoalResponse:
    def __init__(self, accepted: bool) -> None:
        self.accepted = accepted


class LossyActionClient:
    """An action client whose server runs each goal ID once: a copy of a goal it holds is refused as a
    duplicate. ``fate`` says what happens to each copy sent: "lost" (the request never arrives),
    "unanswered" (it arrives and the goal starts, the answer is lost), "answered" (it arrives and the
    answer comes), "refused" (the goal itself is refused)."""

    _action_name = "/explore"

    def __init__(self, *fate: str) -> None:
        from nbv_prob_cnn_msgs.action import Explore

        self._action_type = Explore
        self.fate, self.held, self.ids = list(fate), set(), []

    def wait_for_server(self, timeout_sec: float) -> bool:
        return True

    def send_goal_async(self, goal, feedback_callback=None, goal_uuid=None) -> Future:
        key = bytes(goal_uuid.uuid)
        self.ids.append(key)
        fate = self.fate.pop(0)
        if fate == "lost":
            return Future()
        if key in self.held:
            return Future(GoalResponse(False))  # a duplicate ID
        if fate == "refused":
            return Future(GoalResponse(False))
        self.held.add(key)
        return Future(None if fate == "unanswered" else GoalResponse(True))


def test_a_goal_is_sent_again_with_its_id_and_a_lost_answer_is_recognised():
    pytest.importorskip("nbv_prob_cnn_msgs")
    from nbv_prob_cnn_msgs.action import Explore

    from nbv_prob_cnn.ros.graph import send_goal_with_resend

    goal = Explore.Goal(max_views=2)
    # the first request lost: the second copy starts the goal
    client = LossyActionClient("lost", "answered")
    assert send_goal_with_resend(client, goal, 5.0, resend_s=0.05).accepted
    assert len(client.ids) == 2 and client.ids[0] == client.ids[1]
    # the first request arrived and the goal runs, only its answer was lost: the copy is refused as a
    # duplicate and the handle is the running goal's (its ID)
    client = LossyActionClient("unanswered", "answered")
    handle = send_goal_with_resend(client, goal, 5.0, resend_s=0.05)
    assert handle.accepted and bytes(handle.goal_id.uuid) == client.ids[0]
    # a goal refused for its own reason is a refusal, sent once
    client = LossyActionClient("refused")
    assert not send_goal_with_resend(client, goal, 5.0, resend_s=0.05).accepted
    assert len(client.ids) == 1
    # nothing ever answers: a timeout naming the action and the copies sent
    client = LossyActionClient(*["lost"] * 100)
    with pytest.raises(TimeoutError, match=r"action /explore: no answer to the goal within 0.3 s \(\d+ sent\)"):
        send_goal_with_resend(client, goal, 0.3, resend_s=0.05)
