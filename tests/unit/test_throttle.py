"""max_rate throttling (pure logic): the configured rate is reached under jitter and never exceeded."""

from __future__ import annotations

import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.bridge.core.throttle import SLACK, Throttle


def _run(throttle: Throttle, arrivals: list[float], flush_every: float) -> list[tuple[float, int]]:
    """Feed messages (numbered by arrival) and flush ticks in time order; return (send time, message)."""
    sent: list[tuple[float, int]] = []
    end = (arrivals[-1] if arrivals else 0.0) + 2 * throttle.period
    ticks = [i * flush_every for i in range(int(end / flush_every) + 2)]
    events = sorted([(t, 0, i) for i, t in enumerate(arrivals)] + [(t, 1, -1) for t in ticks])
    for t, kind, i in events:
        out = throttle.offer(i, t) if kind == 0 else throttle.flush(t)
        if out is not None:
            sent.append((t, out))
    return sent


def test_a_jittery_20_hz_source_throttled_to_10_hz_gives_10_hz() -> None:
    rng = random.Random(7)
    arrivals = sorted(k * 0.05 + rng.uniform(-0.003, 0.003) for k in range(1, 401))  # 20 s at 20 Hz
    sent = _run(Throttle(10.0), arrivals, flush_every=0.025)
    assert 199 <= len(sent) <= 201  # "a period since the last send" gives ~192 here


def test_a_slow_source_passes_untouched() -> None:
    arrivals = [k * 0.2 for k in range(50)]  # 5 Hz under a 10 Hz limit
    throttle = Throttle(10.0)
    assert all(throttle.offer(i, t) == i for i, t in enumerate(arrivals))


@given(st.lists(st.floats(0, 30), max_size=300), st.sampled_from([1.0, 5.0, 10.0, 30.0]))
def test_never_above_the_rate_and_the_newest_always_goes_out(times, rate) -> None:
    arrivals = sorted(times)
    throttle = Throttle(rate)
    sent = _run(throttle, arrivals, flush_every=throttle.period / 4)
    gaps = [b[0] - a[0] for a, b in zip(sent, sent[1:], strict=False)]
    assert all(g >= throttle.period * (1 - 2 * SLACK) - 1e-9 for g in gaps)
    for i, (t, _) in enumerate(sent):  # any window holds at most one more message than the rate allows
        window = [s for s, _ in sent[i:] if s - t < 10 * throttle.period]
        assert len(window) <= 11
    numbers = [n for _, n in sent]
    assert numbers == sorted(numbers)  # order kept: a superseded message never goes out late
    if arrivals:
        assert numbers[-1] == len(arrivals) - 1  # the newest is never left behind


@pytest.mark.parametrize("phase", [0.0, 0.005, 0.01, 0.015, 0.02])
def test_each_slot_goes_to_the_freshest_message_whatever_the_flush_timers_phase(phase: float) -> None:
    """A 20 Hz odometry throttled to 10 Hz: the slot goes to the message that comes as it opens, not to the one
    kept 50 ms earlier (a flush that sent that one as soon as the slot opened sent 35 ms old poses for a whole run,
    depending only on the flush timer's phase against the source's)."""
    arrivals = [0.0131 + k * 0.05 for k in range(200)]  # 10 s at 20 Hz
    throttle = Throttle(10.0)
    sent: list[tuple[float, int]] = []
    ticks = [phase + i * 0.025 for i in range(int(10.2 / 0.025))]
    for t, kind, i in sorted([(t, 0, i) for i, t in enumerate(arrivals)] + [(t, 1, -1) for t in ticks]):
        out = throttle.offer(i, t) if kind == 0 else throttle.flush(t)
        if out is not None:
            sent.append((t, out))
    ages = [t - arrivals[n] for t, n in sent]
    assert 99 <= len(sent) <= 101
    # (the first messages teach the throttle the source's period; the last is kept for a next that never comes)
    assert max(ages[2:-1]) < 0.001


def test_a_kept_message_still_goes_out_when_the_next_one_is_late() -> None:
    """The wait for a fresher message is bounded: a source that stops leaves its last message to go out."""
    throttle = Throttle(10.0)
    assert throttle.offer("a", 0.0) == "a"
    assert throttle.offer("b", 0.05) is None  # kept (the source is at 20 Hz)
    assert throttle.flush(0.095) is None  # the next one is due at 0.1, within the wait
    assert throttle.flush(0.12) is None
    assert throttle.flush(0.13) == "b"  # it did not come: the kept one goes, 25 ms of the period past its due


def test_a_fast_sources_last_message_waits_at_most_one_of_its_gaps() -> None:
    """At 1 Hz from a 100 Hz source that stops as the slot opens, the slot waits for the next message no longer
    than the source's own gap (10 ms), not a quarter of the throttle's second."""
    throttle = Throttle(1.0)
    for k in range(80):
        throttle.offer(k, k * 0.01)  # 0 goes out; the rest are kept, newest wins; the slot opens at 0.8
    assert throttle.flush(0.8) is None  # 79's successor is due at 0.8
    assert throttle.flush(0.815) == 79  # it did not come: 79 goes, one source gap late (was: at 1.05)
