"""Failed-login throttling (roslink_mqtt.broker.ratelimit) with a fake clock."""

from __future__ import annotations

import pytest

from roslink_mqtt.broker.ratelimit import REFUSE, KeyThrottle, LoginThrottle

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


PARAMS = {"free_failures": 3, "base_delay": 0.5, "max_delay": 4.0, "max_wait": 10.0, "forget_after": 60.0}


def make(**kw) -> tuple[KeyThrottle, Clock]:
    clock = Clock()
    return KeyThrottle(clock=clock, **{**PARAMS, **kw}), clock


def make_login(**kw) -> tuple[LoginThrottle, Clock]:
    clock = Clock()
    return LoginThrottle(clock=clock, **{**PARAMS, **kw}), clock


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


def test_a_robot_behind_a_guessing_nat_gets_in_at_once() -> None:
    """Ten wrong passwords for other logins from the robot's address: the robot's known-good pair is not slowed."""
    t, _ = make_login()
    t.succeeded("nat", "turtle1")
    for _ in range(10):
        t.reserve("nat", "alice")  # counted as failed until it succeeds
    assert t.reserve("nat", "mallory") != 0.0  # the address is throttled (or refused) for everyone else
    assert t.reserve("nat", "turtle1") == 0.0


def test_a_robot_gets_in_while_another_address_sprays_its_login() -> None:
    t, _ = make_login()
    t.succeeded("robot-ip", "turtle1")
    for i in range(100):
        t.reserve(f"attacker-{i}", "turtle1")
    assert t.reserve("robot-ip", "turtle1") == 0.0
    assert t.reserve("new-ip", "turtle1") != 0.0  # unknown pairs wait for the login's schedule


def test_guesses_spread_over_many_addresses_are_bounded_per_login() -> None:
    """40 guesses at alice from 40 addresses in one instant: only the free ones are checked at once."""
    t, _ = make_login()
    waits = []
    for i in range(40):
        waits.append(t.reserve(f"10.0.0.{i}", "alice"))  # all at the same instant, none answered yet
    immediate = sum(1 for w in waits if w == 0.0)
    assert immediate == PARAMS["free_failures"]
    assert all(w == REFUSE or w <= PARAMS["max_wait"] for w in waits)
    # within max_wait, at most max_wait / base_delay further guesses get a slot
    assert sum(1 for w in waits if w > 0) <= PARAMS["max_wait"] / PARAMS["base_delay"]


def test_a_right_password_takes_its_provisional_failure_back() -> None:
    t, _ = make_login()
    for _ in range(20):
        assert t.reserve("office", "alice") == 0.0
        t.succeeded("office", "alice")
    for i in range(20):  # a new address of hers: not slowed by her own successful logins
        assert t.reserve(f"cafe-{i}", "alice") == 0.0
        t.succeeded(f"cafe-{i}", "alice")


def test_known_good_pairs_are_forgotten_and_bounded() -> None:
    t, clock = make_login(remember_good=100.0, max_addresses=10)
    t.succeeded("a", "turtle1")
    assert t.is_known_good("a", "turtle1")
    clock.now += 101
    assert not t.is_known_good("a", "turtle1")
    for i in range(50):
        t.succeeded(f"ip{i}", "alice")
    assert len(t._good) <= 10
