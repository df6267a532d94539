"""Pure logic of tests/integration/test_shaped_link.py: no processes, no sockets."""

from __future__ import annotations

import random

import pytest

from roslink_mqtt.shaped_link import (
    HIDDEN_QUEUE_MIN,
    MTU_PAYLOAD,
    Schedule,
    Shape,
    ShapedLink,
    Wire,
    kbit,
    parse_args,
    parse_phases,
    phase_at,
)


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


def test_a_chunk_smaller_than_a_link_packet_is_lost_as_that_share_of_one() -> None:
    """A rate-limited link loses ``loss`` of its packets, however small the sender's segments: a sender cutting
    its bytes into fifths of a packet must not stall five times as often."""
    schedule = Schedule(Shape(loss=0.5, rto=0.2), random.Random(3))
    lost = sum(schedule.release_time(i * 1.0, share=0.2) - i * 1.0 > 0.1 for i in range(2000))
    assert 150 < lost < 250  # 10 % of the chunks: half of the packets, a fifth of a packet each


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


def test_a_rate_change_moves_every_waiting_packet_and_a_dead_spot_holds_them() -> None:
    """The byte clock: what is booked keeps its place in the FIFO; only when it leaves follows the rate."""
    wire = Wire(kbit(256))  # 32,000 bytes/s
    end = wire.book(3200, 0.0)
    assert wire.departure(end) == pytest.approx(0.1)
    wire.set_rate(16_000, 0.05)  # half-way through, the rate halves: the other 1,600 bytes take 0.1 s
    assert wire.departure(end) == pytest.approx(0.15)
    assert wire.queued(0.05) == 1600
    wire.set_rate(0, 0.1)  # a dead spot: 800 bytes still to go, and they wait
    assert wire.departure(end) == float("inf")
    assert wire.queued(5.0) == 800
    assert wire.packet_size == MTU_PAYLOAD
    later = wire.book(100, 5.0)  # arrives in the dead spot: behind the 800, not lost
    wire.set_rate(32_000, 6.0)
    assert wire.departure(end) == pytest.approx(6.025)
    assert wire.departure(later) == pytest.approx(6.025 + 100 / 32_000)
    assert wire.queued(7.0) == 0 and wire.carried == 3300
    assert wire.reserve(320, 7.0) == pytest.approx(7.01)  # idle link time is not saved up for later
    with pytest.raises(ValueError):
        wire.set_rate(-1, 8.0)


def test_a_hidden_hop_reads_until_its_bound() -> None:
    wire = Wire(kbit(256), limit=10_000)
    assert wire.room_left() == 10_000
    wire.held += 9_000
    assert wire.room_left() == 1_000  # less than a packet: the hop's readers wait (Wire.room)
    wire.release(9_000)
    assert wire.room_left() == 10_000
    assert Wire(kbit(256)).room_left() > 0  # the visible model has no bound
    with pytest.raises(ValueError):
        Wire(kbit(256), limit=0)


def test_the_default_bound_is_seconds_of_the_highest_rate() -> None:
    link = ShapedLink(("127.0.0.1", 1), Shape(), up_phases=[(10, kbit(1024)), (4, 0)], down_rate=kbit(64),
                      hidden_queue=True)
    assert link.up is not None and link.down is not None
    assert link.up.limit == 1_280_000  # 10 s of 1024 kbit/s
    assert link.down.limit == max(HIDDEN_QUEUE_MIN, 80_000)
    visible = ShapedLink(("127.0.0.1", 1), Shape(), up_rate=kbit(256)).up
    assert visible is not None and visible.limit is None  # the visible model has no bound: the senders hold it
    explicit = ShapedLink(("127.0.0.1", 1), Shape(), up_rate=kbit(256), hidden_queue=True, queue_bytes=5000)
    assert explicit.up is not None and explicit.up.limit == 5000


def test_set_rate_refuses_an_unlimited_direction_and_sets_the_starting_rate_before_the_link_runs() -> None:
    link = ShapedLink(("127.0.0.1", 1), Shape(), up_rate=kbit(256))
    with pytest.raises(ValueError, match="unlimited"):
        link.set_rate(down=1000)
    with pytest.raises(ValueError):
        link.set_rate(up=-1)
    link.set_rate(up=0)  # not started yet: it starts dead
    assert link.up is not None and link.up.rate == 0


def test_phases_repeat_or_play_once_and_keep_the_last() -> None:
    phases = parse_phases("10:1024, 10:128,4:0,10:256")
    assert phases == ((10, 128_000), (10, 16_000), (4, 0), (10, 32_000))
    assert phase_at(phases, 0) == (0, 10)
    assert phase_at(phases, 21) == (2, pytest.approx(3))  # the dead spot
    assert phase_at(phases, 34 + 12) == (1, pytest.approx(8))  # repeated: 34 s a cycle
    assert phase_at(phases, 34 + 12, repeat=False) == (3, float("inf"))  # once: the last phase stays
    assert phase_at(phases, 25, repeat=False) == (3, float("inf"))
    assert phase_at(((5, 1000),), 7) == (0, float("inf"))  # one phase: a fixed rate
    for bad in ["", "10", "10:x", "0:128", "10:-1", "4:0,2:0"]:
        with pytest.raises(ValueError):
            parse_phases(bad)


@pytest.mark.parametrize("bad", [["--phases", "10:128", "--up-kbit", "256"], ["--phases", "4:0"],
                                 ["--hidden-queue"], ["--queue-kb", "100", "--up-kbit", "256"],
                                 ["--hidden-queue", "--up-kbit", "256", "--queue-kb", "0"]])
def test_bad_link_models_are_refused(bad: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        parse_args(["--listen", "127.0.0.1:1", "--to", "127.0.0.1:2"] + bad)
    assert capsys.readouterr().err


def test_the_command_line_builds_both_models_and_phases() -> None:
    args = parse_args(["--listen", "127.0.0.1:1", "--to", "127.0.0.1:2", "--hidden-queue", "--phases",
                       "10:1024,4:0", "--down-kbit", "512", "--queue-kb", "300", "--phases-once"])
    assert args.hidden_queue and args.phases == ((10, 128_000), (4, 0)) and args.phases_once
    assert args.queue_kb == 300 and args.down_phases is None
    visible = parse_args(["--listen", "127.0.0.1:1", "--to", "127.0.0.1:2", "--up-kbit", "256"])
    assert not visible.hidden_queue and visible.phases is None
