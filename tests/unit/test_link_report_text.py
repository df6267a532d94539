"""What people read of a robot's ``state/link`` (roslink_mqtt/protocol/link.py's summary, the monitor's column):
a queue hidden beyond the robot is said as such, with its size, once the path steers."""

from __future__ import annotations

from roslink_mqtt.cli.monitor_view import link_text
from roslink_mqtt.protocol.link import LinkReport, PathReport, StreamReport

SCAN = {"scan": StreamReport("state", True, 5.0, 3.9, 2, 0, 5.0, 20.1)}


def report(path: PathReport | None, measured: bool = True) -> LinkReport:
    return LinkReport("scheduled", 120.4, measured, 3000, 60.0, 2.0, SCAN, path=path)


def test_a_visible_link_reads_as_before() -> None:
    quiet = PathReport(60.0, 62.0, 2.0, 900.0, 0, steering=False)
    assert report(quiet).summary() == "link 120 kbit/s — scan 3.9 Hz of 5.0 (2 superseded)"
    assert not report(quiet).hidden
    assert report(None, measured=False).summary().startswith("link never full (120 kbit/s sent;")
    assert link_text(report(quiet)) == "120k scan 3.9/5"


def test_a_hidden_queue_is_named_with_its_size() -> None:
    # behind a hop the socket's meter never sees the link full: the path's rate is the measurement
    hidden = report(PathReport(60.0, 145.2, 85.2, 120.4, 3, steering=True), measured=False)
    assert hidden.hidden
    assert hidden.summary() == ("link 120 kbit/s (its queue hidden beyond the robot: 85 ms; round trip 145 ms, "
                                "base 60 ms) — scan 3.9 Hz of 5.0 (2 superseded)")
    assert link_text(hidden) == "120k hidden 85ms scan 3.9/5"
    assert LinkReport.from_json(hidden.to_json()) == hidden  # the flag crosses the wire
