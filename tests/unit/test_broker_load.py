"""Overload (roslink_mqtt/broker/load.py): the event loop's lateness turns shedding on and, after a calm second,
off again; while on, one message per state topic every 0.2 s goes through; a fleet overloaded for most of a
minute is told it outgrew one process, once in ten minutes."""

from __future__ import annotations

import pytest

from roslink_mqtt.broker.load import (
    CALM_FOR,
    LAG_ENTER,
    LAG_LEAVE,
    LATE_PROBES,
    LOAD_FIELDS,
    OUTGROWN_REPEAT,
    OUTGROWN_WINDOW,
    STATE_EVERY,
    Counter,
    LoadMonitor,
    Outgrown,
    Rates,
    Shedder,
    load_status,
)

pytestmark = pytest.mark.unit


def test_a_late_loop_is_overloaded_until_it_has_kept_up_for_a_calm_second() -> None:
    load, t = LoadMonitor(), 100.0
    assert not load.observe(LAG_ENTER / 2, t) and not load.overloaded
    for k in range(LATE_PROBES - 1):  # a few late probes are a pause, not an overload
        assert not load.observe(LAG_ENTER * 2, t + 0.1 + k * 0.07)
    assert not load.observe(LAG_ENTER / 2, t + 0.5) and not load.overloaded  # and the count starts over
    for k in range(LATE_PROBES - 1):
        assert not load.observe(LAG_ENTER * 2, t + 0.6 + k * 0.07)
    assert load.observe(LAG_ENTER * 2, t + 1.0) and load.overloaded and load.since == t + 1.0
    t += 1.1
    assert not load.observe(LAG_LEAVE / 2, t)  # calm starts
    assert not load.observe(LAG_ENTER, t + CALM_FOR / 2)  # late again: the calm second starts over
    assert not load.observe(LAG_LEAVE / 2, t + CALM_FOR)
    assert not load.observe(LAG_LEAVE / 2, t + 1.5 * CALM_FOR) and load.overloaded
    assert load.observe(LAG_LEAVE / 2, t + 2 * CALM_FOR + 0.01) and not load.overloaded
    assert load.take_worst() == LAG_ENTER * 2 and load.take_worst() == LAG_LEAVE / 2


def test_while_shedding_each_state_topic_gets_one_message_per_period() -> None:
    shed, t = Shedder(), 10.0
    passed = [n for n in range(100) if shed.admit("roslink/k/r1/state/pose", t + n * 0.01)]  # 100 Hz for 1 s
    assert passed[0] == 0 and len(passed) == 5  # one each STATE_EVERY (0.2 s): 4 of 5 superseded
    assert all(round(STATE_EVERY / 0.01) <= b - a <= round(STATE_EVERY / 0.01) + 1
               for a, b in zip(passed, passed[1:], strict=False))
    assert shed.admit("roslink/k/r2/state/pose", t + 0.005)  # another robot's topic has its own turn
    shed.clear()
    assert shed.admit("roslink/k/r1/state/pose", t + 0.995)


def test_rates_per_second_over_each_status_period() -> None:
    counter = Counter(0.0)
    counter.received, counter.shed = 5000, 1200
    rates = counter.rates(2.0)
    assert (rates.received, rates.shed) == (2500.0, 600.0)
    assert counter.rates(3.0).received == 0.0


def test_a_fleet_overloaded_most_of_a_minute_is_told_once_in_ten_minutes() -> None:
    outgrown = Outgrown()
    said = [t for t in range(0, 1400) if outgrown.sample(float(t), overloaded=t % 10 < 7) is not None]
    assert said and said[0] >= OUTGROWN_WINDOW * 0.9
    assert all(b - a >= OUTGROWN_REPEAT for a, b in zip(said, said[1:], strict=False)) and len(said) == 3
    calm = Outgrown()
    assert all(calm.sample(float(t), overloaded=t % 10 < 4) is None for t in range(0, 300))


def test_the_load_status_has_the_documented_fields() -> None:
    from pathlib import Path

    body = load_status(True, 3.04, 0.0712, Rates(5123.4, 880.2), 2600)
    assert body == {"overloaded": True, "for_s": 3.0, "lag_ms": 71.2, "received_per_s": 5123, "shed_per_s": 880,
                    "shed_total": 2600}
    assert list(body) == list(LOAD_FIELDS)
    protocol = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
    section = protocol[protocol.index("## Broker load"):]
    for name, meaning in LOAD_FIELDS.items():
        assert f"| `{name}` |" in section and meaning in section, name
