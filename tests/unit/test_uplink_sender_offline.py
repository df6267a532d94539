"""The uplink sender when a connection goes (roslink_mqtt/bridge/core/uplink_sender.py): what waits for it is kept on
disk for ``buffer: disk`` streams, in order, and dropped for live state. ROS-free; the links are stand-ins with
real, never connected paho clients (the sender reads their queues and sockets)."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

from roslink_mqtt.bridge.core.spool import Spool
from roslink_mqtt.bridge.core.uplink import Outgoing
from roslink_mqtt.bridge.core.uplink_sender import Uplink
from roslink_mqtt.config import Priority


class Link:
    def __init__(self, name: str) -> None:
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=name)
        self.connected = threading.Event()
        self.connected.set()
        self.sent: list[tuple[str, bytes, int, bool]] = []
        self.queue_delay: Any = None

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> object | None:
        """As MqttLink: dropped (None) while disconnected."""
        if not self.connected.is_set():
            return None
        self.sent.append((topic, payload, qos, retain))
        if len(self.sent) == self.drop_after:
            self.connected.clear()  # the connection goes right after this one
        return object()

    drop_after = -1


def answered(sender: Uplink) -> Uplink:
    """The path's first probe answered (until then only control leaves: the base round trip is learnt first)."""
    now = time.monotonic()
    sender.path.probe_sent(now - 0.05, sender.handed)
    sender.path.probe_answered(now)
    return sender


def test_what_waits_for_a_lost_connection_goes_to_disk_for_buffered_streams_only(tmp_path: Path) -> None:
    """The state connection goes while events and a scan wait behind a busy link (the main one still looks up):
    the events are kept on disk in order, to be sent after reconnecting; the scan, stale by then, is dropped."""
    main, state = Link("main"), Link("state")
    sender = answered(Uplink(main, state))  # type: ignore[arg-type] - the links' surface the sender uses
    spool = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600)
    sender.use_spool(spool)
    events = sender.stream("roslink/turtle1/state/events", Priority.STATE, False, buffered=True)
    scan = sender.stream("roslink/turtle1/state/scan", Priority.STATE, True)
    now = time.monotonic()
    for i in range(3):
        sender.scheduler.offer(events, Outgoing(events.name, b"event %d" % i, 1, False, now))
    sender.scheduler.offer(scan, Outgoing(scan.name, b"scan", 0, False, now))
    state.connected.clear()
    sender._pump(time.monotonic())
    assert state.sent == [] and sender.scheduler.ready() == []
    kept = []
    while (record := spool.next(time.time())) is not None:
        kept.append(record.payload)
    assert kept == [b"event 0", b"event 1", b"event 2"]
    assert (events.dropped, sender.spooled, sender.not_connected) == (0, 3, 1)  # the scan: stale, not replayed


def test_a_connection_lost_in_the_middle_of_draining_the_disk_buffer_loses_nothing(tmp_path: Path) -> None:
    """Records drain after reconnecting (here all on the one connection, which takes several per round); it goes
    again after the second: the third record, refused by the closed link, goes back to the disk and is the first
    sent on the next connection."""
    main = Link("main")
    sender = answered(Uplink(main))  # type: ignore[arg-type]
    spool = Spool(tmp_path, "turtle1", max_bytes=1 << 20, max_age=3600)
    sender.use_spool(spool)
    for i in range(5):
        spool.append("roslink/turtle1/state/events", b"event %d" % i, 1, time.time())
    main.drop_after = 2
    sender._pump(time.monotonic())
    assert [p for _, p, _, _ in main.sent] == [b"event 0", b"event 1"] and not main.connected.is_set()
    main.connected.set()  # back
    sender._pump(time.monotonic())
    assert [p for _, p, _, _ in main.sent] == [b"event %d" % i for i in range(5)]
    assert not spool
