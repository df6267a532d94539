"""Refused logins in the broker's log (roslink_mqtt/broker/refusal_log.py): line by line while few, counted with one
summary line per window in a flood, so that a flood with no login can neither fill the disk nor slow the loop."""

from __future__ import annotations

import logging

import pytest

from roslink_mqtt.broker.refusal_log import RefusalLog, reason_kind

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records]


@pytest.fixture
def refusals(caplog: pytest.LogCaptureFixture) -> tuple[RefusalLog, Clock]:
    caplog.set_level(logging.WARNING, logger="test.refusals")
    clock = Clock()
    return RefusalLog(logging.getLogger("test.refusals"), window=10.0, budget=3, clock=clock), clock


def test_a_few_refusals_are_each_logged_with_who_and_why(refusals, caplog) -> None:
    log, _ = refusals
    log.refused(lambda: "client_id='a' user='alice'", "wrong password", "127.0.0.2")
    log.refused(lambda: "client_id='b' user='bob'", "unknown login", "127.0.0.3")
    assert lines(caplog) == ["refused client_id='a' user='alice': wrong password",
                             "refused client_id='b' user='bob': unknown login"]


def test_a_flood_is_counted_and_summed_up_once_per_window(refusals, caplog) -> None:
    log, clock = refusals
    described = []

    def who(n: int):
        return lambda: described.append(n) or f"user='u{n}'"

    for n in range(1000):
        reason = "wrong password" if n % 3 else "the broker is checking many other passwords (12 waiting, about 1.0 s)"
        log.refused(who(n), reason, f"127.0.4.{n % 50}")
    assert len(lines(caplog)) == 3 + 1  # the budget's lines, and the line that says the rest are counted
    assert described == [0, 1, 2]  # the rest were never even described
    clock.now += 9.0
    log.tick()
    assert len(lines(caplog)) == 4  # the window is not over
    clock.now += 1.0
    log.tick()
    summary = lines(caplog)[-1]
    assert summary == ("refused 997 more logins in the last 10 s (wrong password: 664, the broker is checking many "
                       "other passwords: 333) from 50 addresses"), summary
    log.refused(who(1000), "wrong password", "127.0.0.9")  # a new window: logged again
    assert lines(caplog)[-1] == "refused user='u1000': wrong password"
    assert log.total == 1001


def test_a_quiet_window_ends_without_a_line(refusals, caplog) -> None:
    log, clock = refusals
    log.refused(lambda: "user='a'", "wrong password", None)
    clock.now += 30.0
    log.tick()
    assert lines(caplog) == ["refused user='a': wrong password"]


def test_a_reasons_kind_leaves_its_numbers_out() -> None:
    assert reason_kind("too many failed logins for this login or address; try later") == \
        "too many failed logins for this login or address"
    assert reason_kind("this login already has 4 connections (limit 4)") == "this login already has 4 connections"
    assert reason_kind("") == "refused"
