"""A viewer on a weak link sees fresh state at a lower rate, not a growing queue: latest wins per topic.

A phone on a cellular downlink that subscribes to a robot's camera and pose cannot take every frame. Queued
first in, first out (the kernel's send buffer grows to megabytes, then the broker's queue), every pose it is shown
is as old as the queue is long; dropped at the queue's limit (Mosquitto's ``max_queued_bytes``), it loses new and
old alike. Here, while a client's connection holds more than ``conflate_backlog`` bytes it has not acknowledged, a
QoS 0 delivery of a robot's ``state/…`` topic is not written: it takes that topic's slot for this client, replacing
the message waiting there (latest wins, counted). Held messages are written, smallest first, as the backlog
drains: each one that keeps the backlog under the threshold, and any once it is down to half. Control traffic
(heartbeats, acknowledgements on ``state/ack``, a user's own replies and errors, QoS 1) is never conflated.

Pure logic: the broker (``hardened.py``) measures the backlog and writes; this class only keeps the slots.
"""

from __future__ import annotations

from collections import OrderedDict


class Conflator:
    """One client's latest-wins slots, one per state topic, bounded in number."""

    __slots__ = ("slots", "max_slots", "max_bytes", "bytes", "superseded", "held", "flush_scheduled", "acked",
                 "progress_at")

    def __init__(self, max_slots: int, max_bytes: int = 0) -> None:
        """``max_bytes``: payload bytes the slots may hold together (0: no bound but the slot count)."""
        self.slots: OrderedDict[str, tuple[bytes | bytearray, bool]] = OrderedDict()
        self.max_slots, self.max_bytes = max_slots, max_bytes
        self.bytes = 0
        self.superseded = 0  # messages replaced in their slot before they could be written
        self.held = 0  # messages that went through a slot
        self.flush_scheduled = False
        self.acked = -1  # the client's acknowledged-bytes counter when it last made progress
        self.progress_at = 0.0  # monotonic: when that was

    def __bool__(self) -> bool:
        return bool(self.slots)

    def hold(self, topic: str, data: bytes | bytearray, retain: bool) -> bool:
        """Keep ``data`` as ``topic``'s newest; False when the slots are full, in number or bytes (the caller drops
        it, as without conflation)."""
        old = self.slots.get(topic)
        size = self.bytes - (len(old[0]) if old is not None else 0) + len(data)
        if (old is None and len(self.slots) >= self.max_slots) or (self.max_bytes and size > self.max_bytes):
            return False
        if old is not None:
            self.superseded += 1
        else:
            self.held += 1
        self.slots[topic] = (data, retain)  # a replaced slot keeps its place in line
        self.bytes = size
        return True

    def clear(self) -> None:
        self.slots.clear()
        self.bytes = 0

    def progress(self, acked: int, now: float) -> float:
        """Feed the client's acknowledged-bytes counter; seconds since it last grew (the client stopped reading)."""
        if acked != self.acked:
            self.acked, self.progress_at = acked, now
        return now - self.progress_at

    def release(self, backlog: int, threshold: int) -> list[tuple[str, bytes | bytearray, bool]]:
        """What may be written now, smallest first: each message that keeps the backlog within ``threshold``, and
        any while the backlog is at most half of it (so a message larger than the threshold still goes). Small
        state (a pose) is not made to wait behind a camera frame: the broker does not know the robot's priorities,
        and small state is what people read most. The rest stays in its slot."""
        out = []
        for topic, (data, retain) in sorted(self.slots.items(), key=lambda item: len(item[1][0])):
            if backlog > threshold // 2 and backlog + len(data) > threshold:
                break
            out.append((topic, data, retain))
            backlog += len(data)
        for topic, data, _retain in out:
            del self.slots[topic]
            self.bytes -= len(data)
        return out
