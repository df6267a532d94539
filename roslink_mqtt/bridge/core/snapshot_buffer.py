"""The snapshot ring buffer: the last seconds of chosen ROS topics as CDR, and the MCAP file made of them. ROS-free.

ROS hands the bridge each message already serialized (a raw subscription: no conversion, no Python message object),
so keeping a topic costs a deque append and the bytes. The buffer holds at most ``seconds`` and ``max_bytes``; the
oldest go first. :meth:`SnapshotBuffer.build` writes the last ``last`` seconds as MCAP with the ``ros2`` profile:
one ``cdr`` channel per topic, its schema the type's full ``.msg`` definition (``ros2msg``), zstd chunks — what
``ros2 bag``, Foxglove and ``mcap-ros2-support`` read.
"""

from __future__ import annotations

import hashlib
import io
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ...config import SnapshotSettings, SnapshotTopic


@dataclass(frozen=True, slots=True)
class SnapshotFile:
    """A finished snapshot: the MCAP bytes and what is in them."""

    data: bytes
    sha256: str
    start: int  # ns, first message (0: none)
    end: int  # ns, last message
    messages: int
    topics: tuple[str, ...]


class SnapshotBuffer:
    """``settings.topics``' messages of the last ``settings.seconds`` (and ``max_bytes``); :meth:`add` from ROS
    callbacks (any thread), :meth:`build` from a worker thread. ``definition`` gives a type's ``ros2msg`` text
    (bridge/core/msgdef.py) and ``clock`` the time in ns (the tests' own)."""

    def __init__(self, settings: SnapshotSettings, definition: Callable[[str], str],
                 clock: Callable[[], int] = time.time_ns) -> None:
        self.settings, self.definition, self.clock = settings, definition, clock
        self.topics: Sequence[SnapshotTopic] = settings.topics
        self._messages: deque[tuple[int, int, bytes]] = deque()  # (log time ns, topic index, CDR)
        self._bytes = 0
        self._lock = threading.Lock()
        self.dropped_for_size = 0  # messages that left before their time because of max_bytes

    def add(self, index: int, data: bytes) -> None:
        """Keep one serialized message of ``self.topics[index]``, received now."""
        now = self.clock()
        horizon = now - int(self.settings.seconds * 1e9)
        with self._lock:
            self._messages.append((now, index, data))
            self._bytes += len(data)
            messages = self._messages
            while messages and (messages[0][0] < horizon or self._bytes > self.settings.max_bytes):
                gone = messages.popleft()
                self._bytes -= len(gone[2])
                if gone[0] >= horizon:
                    self.dropped_for_size += 1

    def held(self) -> tuple[int, int]:
        """(messages, bytes) held now."""
        with self._lock:
            return len(self._messages), self._bytes

    def build(self, last: float) -> SnapshotFile:
        """The last ``last`` seconds as an MCAP file (a copy taken under the lock, written outside it)."""
        from mcap.writer import CompressionType, Writer

        since = self.clock() - int(last * 1e9)
        with self._lock:
            taken = [m for m in self._messages if m[0] >= since]
        out = io.BytesIO()
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="roslink-mqtt bridge")
        channels: dict[int, int] = {}
        sequence: dict[int, int] = {}
        for log_time, index, data in taken:
            if index not in channels:
                topic = self.topics[index]
                schema = writer.register_schema(topic.ros_type, "ros2msg",
                                                self.definition(topic.ros_type).encode())
                channels[index] = writer.register_channel(topic.ros_topic, "cdr", schema)
                sequence[index] = 0
            sequence[index] += 1
            writer.add_message(channels[index], log_time, data, log_time, sequence[index])
        writer.finish()
        data = out.getvalue()
        return SnapshotFile(data, hashlib.sha256(data).hexdigest(), taken[0][0] if taken else 0,
                            taken[-1][0] if taken else 0, len(taken),
                            tuple(self.topics[i].ros_topic for i in sorted(channels)))
