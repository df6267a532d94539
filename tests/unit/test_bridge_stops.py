"""Emergency stops arrive on two connections and are obeyed once (roslink_mqtt/bridge/core/stops.py): pure logic."""

from __future__ import annotations

from roslink_mqtt.bridge.core.stops import MAX_KEPT, WINDOW, StopDedup

TOPIC = "roslink/turtle1/from/alice/cmd/emergency_stop"


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_first_copy_is_obeyed_the_second_dropped_and_a_resend_obeyed_again() -> None:
    clock = Clock()
    stops = StopDedup(clock)
    body = b'{"sequence_number": 7, "payload": {}}'
    assert stops.seen(TOPIC, body) is False  # obey
    clock.now = 0.2
    assert stops.seen(TOPIC, body) is True  # the copy from the other connection
    assert stops.seen(TOPIC, body) is False  # the same bytes again: a new press
    assert stops.seen(TOPIC.replace("alice", "admin"), body) is False  # another user's stop is its own
    clock.now = 0.2 + WINDOW + 0.1
    assert stops.seen(TOPIC, body) is False  # a copy that never came is forgotten after the window


def test_memory_stays_bounded_whatever_is_sent() -> None:
    """A flood of distinct large stop payloads (an operator's misbehaving program) keeps only digests, and no more
    than MAX_KEPT of them."""
    clock = Clock()
    stops = StopDedup(clock)
    big = bytearray(100_000)
    for i in range(3 * MAX_KEPT):
        big[:8] = i.to_bytes(8, "big")
        assert stops.seen(TOPIC, big) is False
    assert len(stops) <= MAX_KEPT
    assert all(len(key[1]) == 16 for key in stops._kept)  # digests, not payloads
