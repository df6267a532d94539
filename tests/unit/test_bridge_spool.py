"""The bridge's disk buffer for ``buffer: disk`` rules (roslink_mqtt/bridge/core/spool.py): order, bounds, restarts."""

from __future__ import annotations

from roslink_mqtt.bridge.core.spool import Spool


def _drain(spool: Spool, now: float = 100.0) -> list[bytes]:
    out = []
    while (record := spool.next(now)) is not None:
        out.append(record.payload)
    return out


def test_records_come_back_oldest_first_with_their_topic_qos_and_time(tmp_path) -> None:
    spool = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600)
    assert not spool
    spool.append("roslink/turtle1/state/events", b"first", 1, 10.0)
    spool.append("roslink/turtle1/state/log", b"second", 0, 11.0)
    assert spool
    first = spool.next(20.0)
    assert first is not None and (first.topic, first.payload, first.qos, first.stamp) == (
        "roslink/turtle1/state/events", b"first", 1, 10.0)
    assert _drain(spool) == [b"second"] and not spool


def test_a_restart_resumes_after_what_was_committed(tmp_path) -> None:
    spool = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600)
    for i in range(5):
        spool.append("t", f"m{i}".encode(), 0, float(i))
    assert spool.next(10.0).payload == b"m0" and spool.next(10.0).payload == b"m1"
    spool.commit()
    spool.next(10.0)  # read, not committed: sent again after a restart (at least once)
    again = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600)
    assert _drain(again, 10.0) == [b"m2", b"m3", b"m4"]


def test_a_full_queue_loses_its_oldest_and_counts_them(tmp_path) -> None:
    spool = Spool(tmp_path, "turtle1", max_bytes=16_384, max_age=3600)
    for i in range(200):
        spool.append("t", f"{i:04d}".encode() * 25, 0, float(i))  # 100-byte payloads, ~20 kB in all
    assert spool.bytes <= 16_384
    got = _drain(spool, 200.0)
    assert spool.dropped_full > 0 and len(got) + spool.dropped_full == 200
    assert got == sorted(got) and got[-1].startswith(b"0199")  # the newest survive, in order


def test_records_older_than_max_age_are_skipped_and_counted(tmp_path) -> None:
    spool = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=60)
    spool.append("t", b"old", 0, 0.0)
    spool.append("t", b"new", 0, 90.0)
    assert _drain(spool, 100.0) == [b"new"] and spool.dropped_old == 1


def test_a_record_torn_by_a_crash_is_ignored(tmp_path) -> None:
    spool = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600)
    spool.append("t", b"whole", 0, 1.0)
    segment = next(tmp_path.glob("turtle1-*.spool"))
    with open(segment, "ab") as f:
        f.write(b"\x00\x00\x01\x00partial")  # a record header promising 256 bytes, cut short
    assert _drain(Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600), 2.0) == [b"whole"]
    assert Spool.whole_records(segment.read_bytes()) == 1  # what a test or a tool counts from outside: whole ones


def test_a_record_that_could_not_be_sent_is_put_back(tmp_path) -> None:
    spool = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600)
    for i in range(3):
        spool.append("t", b"%d" % i, 1, 100.0)
    assert spool.next(100.0).payload == b"0"
    assert spool.next(100.0).payload == b"1"
    spool.unread()  # "1" was refused by a closed connection
    assert _drain(spool) == [b"1", b"2"]
