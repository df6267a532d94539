"""The suite's waits (tests/support/waits.py) fail when they should and return as soon as they can."""

from __future__ import annotations

import itertools
import time

import pytest

from tests.support.waits import never, paced, stays, wait_until


def test_wait_until_returns_the_first_truthy_value_without_waiting_out_the_deadline() -> None:
    values = iter([None, 0, [], "row"])
    started = time.monotonic()
    assert wait_until("a row", lambda: next(values), timeout=5.0, period=0.001) == "row"
    assert time.monotonic() - started < 1.0


def test_wait_until_names_what_it_waited_for_and_the_last_value() -> None:
    with pytest.raises(AssertionError, match=r"waiting for the zero twist \(last: 0\)"):
        wait_until("the zero twist", lambda: 0, timeout=0.05, period=0.01)


def test_wait_until_looks_at_least_once_even_past_its_deadline() -> None:
    looks: list[int] = []
    assert wait_until("it", lambda: looks.append(1) or "here", timeout=0.0) == "here"
    with pytest.raises(AssertionError):
        wait_until("it", lambda: looks.append(1), timeout=0.0)
    assert len(looks) == 2


def test_stays_fails_at_the_first_lapse_not_at_the_end_of_the_window() -> None:
    looks = itertools.count()
    started = time.monotonic()
    with pytest.raises(AssertionError, match="moving stopped holding"):
        stays("moving", lambda: next(looks) < 3, seconds=10.0, period=0.001)
    assert time.monotonic() - started < 1.0


def test_stays_and_never_pass_a_window_that_holds() -> None:
    started = time.monotonic()
    stays("up", lambda: True, seconds=0.05, period=0.01)
    never("a twist", lambda: None, seconds=0.05, period=0.01)
    assert time.monotonic() - started >= 0.1


def test_never_fails_as_soon_as_the_thing_happens() -> None:
    looks = itertools.count()
    with pytest.raises(AssertionError, match=r"a moving twist happened \(got 'twist'\)"):
        never("a moving twist", lambda: "twist" if next(looks) == 2 else None, seconds=10.0, period=0.001)


def test_paced_ticks_on_a_schedule_and_stops_at_its_bounds() -> None:
    started = time.monotonic()
    assert list(paced(0.01, count=5)) == [0, 1, 2, 3, 4]
    assert time.monotonic() - started >= 0.04
    assert list(paced(0.001, count=100, stop=lambda: True)) == []
    assert len(list(paced(0.01, within=0.05))) <= 6


def test_paced_refuses_a_stream_without_a_bound() -> None:
    with pytest.raises(ValueError, match="count or within"):
        next(paced(0.01, stop=lambda: False))
