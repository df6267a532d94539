"""The viewers' connection is read at a bounded rate (bridge/core/intake.py): bursts pass, a flood is spread out."""

from __future__ import annotations

import pytest

from roslink_mqtt.bridge.core.intake import BURST_TIME, MIN_BURST, Intake


def test_a_few_messages_pass_at_once() -> None:
    intake = Intake(500.0)
    assert [intake.wait(10.0) for _ in range(int(500 * BURST_TIME))] == [0.0] * int(500 * BURST_TIME)
    assert Intake(10.0).burst == MIN_BURST  # a small rate still lets a viewer's few requests through at once


def test_a_reader_that_sleeps_what_it_is_told_reads_at_the_rate() -> None:
    """10,000 messages arriving at once: the reader that sleeps each wait handles them at the rate, within a
    burst, whatever the order of arrival."""
    rate, now = 500.0, 100.0
    intake = Intake(rate)
    for _ in range(10_000):
        now += intake.wait(now) + 1e-5  # the wait, then the message's own handling time
    took = now - 100.0
    assert (10_000 - intake.burst) / rate <= took <= 10_000 / rate + 0.1, took
    assert intake.waited == pytest.approx(took - 10_000 * 1e-5, rel=0.01)


def test_quiet_spells_refill_only_up_to_the_burst() -> None:
    intake = Intake(100.0)
    for _ in range(int(intake.burst)):
        assert intake.wait(0.0) == 0.0
    assert intake.wait(0.0) == pytest.approx(0.01)  # the next one is owed a token
    # an hour of quiet gives one burst back, not an hour's worth
    assert sum(intake.wait(3600.0) == 0.0 for _ in range(1000)) == int(intake.burst)


def test_a_rate_must_be_positive() -> None:
    with pytest.raises(ValueError, match="positive"):
        Intake(0.0)
