"""Failed-login throttling (roslink_mqtt.broker.ratelimit) with a fake clock."""

from __future__ import annotations

import pytest

from roslink_mqtt.broker.ratelimit import REFUSE, KeyThrottle, LoginThrottle


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
        t.failed("nat", "alice")
    assert t.reserve("nat", "mallory") != 0.0  # the address is throttled (or refused) for everyone else
    assert t.reserve("nat", "turtle1") == 0.0


def test_a_robot_gets_in_while_another_address_sprays_its_login() -> None:
    t, _ = make_login()
    t.succeeded("robot-ip", "turtle1")
    for i in range(100):
        t.failed(f"attacker-{i}", "turtle1")
    assert t.reserve("robot-ip", "turtle1") == 0.0
    assert t.reserve("new-ip", "turtle1") != 0.0  # unknown pairs wait for the login's schedule


def test_guesses_spread_over_many_addresses_are_bounded_per_login() -> None:
    """40 guesses at alice from 40 addresses in one instant: only the free ones are checked at once."""
    t, _ = make_login()
    admitted = [t.try_begin(f"10.0.0.{i}", "alice") for i in range(40)]  # all at once, none answered yet
    assert sum(1 for a in admitted if a is not None) == PARAMS["free_failures"]
    for i, slot in enumerate(admitted):  # the first ones were wrong
        if slot is not None:
            t.failed(f"10.0.0.{i}", "alice")
            t.end(slot)
    waits = []
    for i in range(40):  # the rest, as places free up: every one now waits for its slot, or is refused
        slot = t.try_begin(f"10.1.0.{i}", "alice")
        assert slot is not None
        waits.append(t.reserve(f"10.1.0.{i}", "alice"))
        t.failed(f"10.1.0.{i}", "alice")
        t.end(slot)
    assert all(w == REFUSE or 0 < w <= PARAMS["max_wait"] for w in waits)
    assert sum(1 for w in waits if w > 0) <= PARAMS["max_wait"] / PARAMS["base_delay"]


def test_a_fleet_reconnecting_at_once_from_one_address_is_never_refused() -> None:
    """400 robots behind one address after a broker restart (no pair known good): a few checked at a time,
    each gets in once the ones before it are answered; nobody is refused or slowed."""
    t, _ = make_login()
    waiting = [f"r{i:04d}" for i in range(400)]
    in_check: list[tuple[str, tuple[tuple[str, str], ...]]] = []
    rounds = 0
    while waiting or in_check:
        rounds += 1
        still = []
        for login in waiting:
            slot = t.try_begin("gateway", login)
            if slot is None:
                still.append(login)
            else:
                assert t.reserve("gateway", login) == 0.0
                in_check.append((login, slot))
        waiting = still
        for login, slot in in_check:  # their passwords were right
            t.succeeded("gateway", login)
            t.end(slot)
        in_check = []
    assert rounds <= 400 // PARAMS["free_failures"] + 1
    assert t.reserve("gateway", "intruder") == 0.0  # right passwords are no failures


def test_right_passwords_never_count_as_failures() -> None:
    t, _ = make_login()
    for _ in range(20):
        slot = t.try_begin("office", "alice")
        assert slot is not None and t.reserve("office", "alice") == 0.0
        t.succeeded("office", "alice")
        t.end(slot)
    for i in range(20):  # a new address of hers: not slowed by her own successful logins
        slot = t.try_begin(f"cafe-{i}", "alice")
        assert slot is not None and t.reserve(f"cafe-{i}", "alice") == 0.0
        t.succeeded(f"cafe-{i}", "alice")
        t.end(slot)


def test_known_good_pairs_are_forgotten_and_bounded() -> None:
    t, clock = make_login(remember_good=100.0, max_addresses=10)
    t.succeeded("a", "turtle1")
    assert t.is_known_good("a", "turtle1")
    clock.now += 101
    assert not t.is_known_good("a", "turtle1")
    for i in range(50):
        t.succeeded(f"ip{i}", "alice")
    assert len(t._good) <= 10
