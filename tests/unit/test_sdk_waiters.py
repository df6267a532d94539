"""A robot's refusal wakes the caller waiting for it (client/waiters.py): by topic, and by sequence number when the
caller gave one (a report that names none matches any); nobody else, and nobody once the wait is over."""

from __future__ import annotations

import threading

from roslink_mqtt.client.errors import RobotError
from roslink_mqtt.client.waiters import ErrorWaiters

TOPIC = "roslink/turtle1/from/alice/cmd/twist"


def refusal(topic: str = TOPIC, sequence: int | None = None) -> RobotError:
    return RobotError("turtle1", topic, "not the control holder", sequence_number=sequence)


def test_a_refusal_wakes_the_caller_of_its_topic_and_sequence() -> None:
    waiters = ErrorWaiters()
    with waiters.waiting(TOPIC, 7) as seven, waiters.waiting(TOPIC, 8) as eight, \
            waiters.waiting("roslink/turtle1/from/alice/cmd/arm") as other:
        assert waiters.deliver(refusal(sequence=7))
        assert seven.wait(0) is not None and eight.wait(0) is None and other.wait(0) is None
        assert waiters.deliver(refusal())  # a report without a sequence number: every caller of the topic
        assert eight.wait(0) is not None and other.wait(0) is None
    assert not waiters.deliver(refusal(sequence=7))  # the waits are over: nobody is told


def test_a_shared_event_ends_the_wait_either_way() -> None:
    waiters, done = ErrorWaiters(), threading.Event()
    with waiters.waiting(TOPIC, done=done) as waiter:
        waiters.deliver(refusal())
        assert done.is_set() and waiter.errors[0].error == "not the control holder"
