"""Pure logic of tests/integration/test_shaped_link.py: no processes, no sockets."""

from __future__ import annotations

import random

import pytest

from roslink_mqtt.shaped_link import MTU_PAYLOAD, Schedule, Shape, Wire, kbit, parse_args


def test_schedule_never_reorders_and_adds_the_delay() -> None:
    schedule = Schedule(Shape(delay=0.05, jitter=0.03), random.Random(1))
    releases = [schedule.release_time(i * 0.02) for i in range(500)]  # 50 Hz, as in the spiral bench
    assert releases == sorted(releases)  # a late chunk holds up the ones behind it, like TCP
    extra = [r - i * 0.02 for i, r in enumerate(releases)]
    assert min(extra) >= 0.0
    assert 0.05 <= sum(extra) / len(extra) < 0.075  # the delay, plus what holding up late chunks adds


def test_a_lost_chunk_costs_a_retransmission_timeout() -> None:
    schedule = Schedule(Shape(delay=0.01, loss=0.5, rto=0.2), random.Random(2))
    extra = [schedule.release_time(i * 1.0) - i * 1.0 for i in range(200)]  # far apart: no holding up
    lost = [e for e in extra if e > 0.1]
    assert 60 < len(lost) < 140
    assert all(abs(e - 0.21) < 1e-9 for e in lost)
    assert all(abs(e - 0.01) < 1e-9 for e in extra if e <= 0.1)


@pytest.mark.parametrize("bad", [["--delay-ms", "-1"], ["--loss", "1.5"], ["--to", "nohostport"]])
def test_bad_shapes_are_refused(bad: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--listen", "127.0.0.1:1", "--to", "127.0.0.1:2"] + bad
    with pytest.raises(SystemExit) as exit_info:
        parse_args(argv)
    assert exit_info.value.code == 2
    assert capsys.readouterr().err


def test_the_wire_carries_one_packet_at_a_time_in_arrival_order() -> None:
    wire = Wire(kbit(256))  # 32,000 bytes/s
    assert wire.packet_size == MTU_PAYLOAD
    first = wire.reserve(1600, 0.0)  # 50 ms of link time
    second = wire.reserve(3200, 0.01)  # arrived while the first was on the wire: waits for it
    assert first == pytest.approx(0.05)
    assert second == pytest.approx(0.15)
    assert wire.reserve(320, 1.0) == pytest.approx(1.01)  # an idle wire starts at once
    assert wire.carried == 5120
    assert Wire(kbit(100_000)).packet_size == 12_500  # fast links move ~1 ms of data at once
    with pytest.raises(ValueError):
        Wire(0)


def test_bad_rates_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        parse_args(["--listen", "127.0.0.1:1", "--to", "127.0.0.1:2", "--up-kbit", "-5"])
    assert "must not be negative" in capsys.readouterr().err
    args = parse_args(["--listen", "127.0.0.1:1", "--to", "127.0.0.1:2", "--up-kbit", "256"])
    assert kbit(args.up_kbit) == 32_000 and args.down_kbit == 0
