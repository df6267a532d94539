"""A paced lane's writes (bridge/pacer.py): the token bucket, and the wrapper under paho's socket writes."""

from __future__ import annotations

import pytest

from roslink_mqtt.bridge.pacer import MIN_BURST, SLEEP_MAX, Pacer, paced_send

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def test_unpaced_writes_go_through_whole() -> None:
    assert Pacer().grant(4_000_000, 0.0) == (4_000_000, 0.0)


def test_a_large_message_leaves_at_the_rate_in_small_bursts() -> None:
    """A 4 MB map written through a 1 Mbit/s-paced lane: the socket gets it at that rate, 20 ms worth at a time
    (never in one go, which behind a hop would be 32 s of a hidden queue ahead of everything else)."""
    clock, pacer = Clock(), Pacer()
    pacer.rate = 125_000.0
    written: list[int] = []
    write = paced_send(pacer, lambda buf: written.append(len(buf)) or len(buf), clock.sleep, clock)
    left = 1_000_000
    while left:
        try:
            left -= write(b"x" * left)
        except BlockingIOError:
            clock.sleep(0.001)  # paho's next turn
    assert max(written) <= max(MIN_BURST, 125_000 * 0.02)
    assert clock.now == pytest.approx(1_000_000 / 125_000, rel=0.05)


def test_a_lane_without_tokens_waits_once_then_reports_a_full_socket() -> None:
    clock, pacer = Clock(), Pacer()
    pacer.rate = 10.0  # 1,500 bytes of burst, then 10 bytes/s
    write = paced_send(pacer, len, clock.sleep, clock)
    assert write(b"x" * 1_500) == 1_500
    with pytest.raises(BlockingIOError):
        write(b"x" * 100)
    assert clock.now == pytest.approx(SLEEP_MAX)  # waited once, briefly: paho's thread reads between turns


def test_what_the_socket_did_not_take_is_refunded() -> None:
    clock, pacer = Clock(), Pacer()
    pacer.rate = 1_000.0
    write = paced_send(pacer, lambda buf: 100, clock.sleep, clock)  # a socket that takes 100 bytes
    assert write(b"x" * 1_500) == 100
    assert write(b"x" * 1_400) == 100  # the 1,400 not taken were kept: no wait
    assert clock.now == 0.0


def test_unpacing_lets_the_rest_through_at_once() -> None:
    pacer = Pacer()
    pacer.rate = 1_000.0
    assert pacer.grant(10_000, 0.0)[0] == MIN_BURST
    pacer.rate = None
    assert pacer.grant(10_000, 0.0) == (10_000, 0.0)
