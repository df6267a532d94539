"""The broker's latest-wins slots for a backed-up client (roslink_mqtt/broker/conflate.py): pure logic."""

from __future__ import annotations

from roslink_mqtt.broker.conflate import Conflator


def test_latest_wins_per_topic_and_the_slot_keeps_its_place() -> None:
    c = Conflator(max_slots=8)
    assert c.hold("r/t1/state/pose", b"p1", False) and c.hold("r/t1/state/camera", b"c" * 100, False)
    assert c.hold("r/t1/state/pose", b"p2", False)  # replaces p1
    assert (c.held, c.superseded) == (2, 1)
    assert c.release(0, 1000) == [("r/t1/state/pose", b"p2", False), ("r/t1/state/camera", b"c" * 100, False)]
    assert not c


def test_small_messages_go_as_the_backlog_allows_and_a_large_one_once_it_is_down_to_half() -> None:
    c = Conflator(max_slots=8)
    c.hold("cam", b"c" * 20_000, False)
    c.hold("pose", b"p" * 400, True)
    assert c.release(15_000, 16_000) == [("pose", b"p" * 400, True)]  # fits; the frame does not
    assert list(c.slots) == ["cam"]
    assert c.release(9_000, 16_000) == []  # still over half: the frame waits
    assert c.release(8_000, 16_000) == [("cam", b"c" * 20_000, False)]  # larger than the threshold, yet it goes


def test_slots_are_bounded() -> None:
    c = Conflator(max_slots=2)
    assert c.hold("a", b"1", False) and c.hold("b", b"2", False)
    assert not c.hold("c", b"3", False)  # the caller drops it, as without conflation
    assert c.hold("a", b"4", False)  # an existing slot is always replaced


def test_slots_are_bounded_in_bytes_and_a_client_that_stops_reading_is_seen() -> None:
    c = Conflator(max_slots=8, max_bytes=1000)
    assert c.hold("map", b"m" * 900, False)
    assert not c.hold("cam", b"c" * 200, False)  # over the byte bound: dropped, as without conflation
    assert c.hold("map", b"m" * 1000, False) and c.bytes == 1000  # a replacement within the bound
    c.release(0, 10_000)
    assert c.bytes == 0
    assert c.progress(5000, 10.0) == 0.0 and c.progress(5000, 12.5) == 2.5  # no acknowledgement since 10.0
    assert c.progress(6000, 13.0) == 0.0  # it read again
