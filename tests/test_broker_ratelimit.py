"""Failed-login throttling (roslink_mqtt.broker.ratelimit) with a fake clock."""

from __future__ import annotations

import pytest

from roslink_mqtt.broker.ratelimit import REFUSE, LoginThrottle


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def make(**kw) -> tuple[LoginThrottle, Clock]:
    clock = Clock()
    return LoginThrottle(clock=clock, **{"free_failures": 3, "base_delay": 0.5, "max_delay": 4.0,
                                         "max_wait": 10.0, "forget_after": 60.0, **kw}), clock


def test_first_failures_are_free_then_spacing_doubles_up_to_the_cap() -> None:
    t, clock = make()
    for _ in range(3):
        assert t.reserve("a") == 0.0
        t.failed("a")
    waits = []
    for _ in range(6):
        wait = t.reserve("a")
        waits.append(wait)
        clock.now += wait  # the attempt waits its slot, then fails
        t.failed("a")
    assert waits == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]


def test_concurrent_attempts_get_successive_slots_and_overflow_is_refused() -> None:
    t, _ = make()
    for _ in range(3):
        t.failed("a")
    # 3 failures -> spacing 0.5 s; ten attempts at the same instant queue up, then overflow
    waits = [t.reserve("a") for _ in range(25)]
    assert waits[:3] == [0.5, 1.0, 1.5]
    assert max(w for w in waits if w != REFUSE) <= 10.0
    assert waits[-1] == REFUSE


def test_other_addresses_are_not_affected_and_failures_are_forgotten() -> None:
    t, clock = make()
    for _ in range(10):
        t.failed("attacker")
    assert t.reserve("attacker") > 0
    assert t.reserve("someone-else") == 0.0
    clock.now += 61
    assert t.failures("attacker") == 0
    assert t.reserve("attacker") == 0.0


def test_memory_is_bounded() -> None:
    t, _ = make(max_addresses=100)
    for i in range(1000):
        t.failed(f"10.0.{i // 256}.{i % 256}")
    assert len(t._records) <= 100


def test_bad_parameters() -> None:
    with pytest.raises(ValueError):
        LoginThrottle(base_delay=5, max_delay=1)
