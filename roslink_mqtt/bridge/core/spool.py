"""A bounded on-disk queue for state that must survive an outage: rules with ``buffer: disk``. ROS-free.

While the broker is unreachable the bridge drops live state (a pose is stale by the time the link is back), but
events, logs and slow telemetry are worth keeping: they are appended here, in files that survive a bridge
restart, and sent after reconnecting, oldest first, at the lowest priority (live data goes first). The queue is
bounded in bytes (the oldest records go first when it is full) and in age (records older than ``max_age`` are
skipped when read); both losses are counted.

Layout: ``<dir>/<robot>-<n>.spool`` segment files, each a sequence of records
``[u32 size][f64 wall time][u8 qos][u16 topic length][topic][payload]`` (big-endian). A record is committed once
it is handed to the network; the read position lives in memory and in ``<dir>/<robot>.pos`` (segment, offset),
written after each segment is finished, so a restart may resend at most one segment's worth (at-least-once).
A torn record at the end of a segment (a crash while writing) is skipped.
"""

from __future__ import annotations

import builtins  # in Spool's signatures: its `bytes` property hides the built-in there
import logging
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("roslink_mqtt.bridge.core.spool")

_HEAD = struct.Struct(">IdBH")  # size of what follows the size field, wall time, qos, topic length
SEGMENT_BYTES = 256 * 1024  # a new segment file after this many bytes (less for a small queue)


def buffer_dir(configured: str | None) -> Path:
    """Where the disk buffer lives: robots.yaml's ``bridge.buffer_dir``, else systemd's ``$STATE_DIRECTORY`` (the
    unit's ``StateDirectory=``), else ``$XDG_STATE_HOME/roslink-mqtt`` (``~/.local/state/roslink-mqtt``)."""
    if configured:
        return Path(configured).expanduser()
    if os.environ.get("STATE_DIRECTORY"):
        return Path(os.environ["STATE_DIRECTORY"].split(":")[0])
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "roslink-mqtt"


@dataclass(frozen=True, slots=True)
class Record:
    topic: str
    payload: bytes
    qos: int
    stamp: float  # wall time when the bridge received it


class Spool:
    """Append while offline, read back in order once online; bounded by ``max_bytes`` and ``max_age``."""

    def __init__(self, directory: str | os.PathLike[str], name: str, *, max_bytes: int, max_age: float) -> None:
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.name, self.max_bytes, self.max_age = name, max_bytes, max_age
        self.segment_bytes = max(4096, min(SEGMENT_BYTES, max_bytes // 4))  # a full queue drops a quarter at most
        self.dropped_full = 0  # records lost because the queue was full
        self.dropped_old = 0  # records skipped because they were older than max_age
        self._pos_file = self.dir / f"{name}.pos"
        self._segments = sorted(self._segment_numbers())
        self._sizes = {n: self._size_on_disk(n) for n in self._segments}  # kept here: no stat() per record
        self._cache: tuple[int, int, bytes] | None = None  # (segment, size, its bytes): the segment being read
        self._read_segment, self._read_offset = self._load_position()
        self._unread: tuple[int, int] | None = None  # where the record next() returned last begins

    # -- files ---------------------------------------------------------------------------------------------
    def _segment_numbers(self) -> list[int]:
        out = []
        for path in self.dir.glob(f"{self.name}-*.spool"):
            try:
                out.append(int(path.stem.rsplit("-", 1)[1]))
            except ValueError:
                continue
        return out

    def _path(self, number: int) -> Path:
        return self.dir / f"{self.name}-{number}.spool"

    def _load_position(self) -> tuple[int, int]:
        try:
            segment, offset = (int(x) for x in self._pos_file.read_text().split())
        except (OSError, ValueError):
            return (self._segments[0] if self._segments else 0), 0
        if self._segments and segment < self._segments[0]:
            return self._segments[0], 0
        return segment, offset

    def _save_position(self) -> None:
        tmp = self._pos_file.with_suffix(".tmp")
        tmp.write_text(f"{self._read_segment} {self._read_offset}\n")
        os.replace(tmp, self._pos_file)

    def _size_on_disk(self, number: int) -> int:
        try:
            return self._path(number).stat().st_size
        except OSError:
            return 0

    @property
    def bytes(self) -> int:
        """What the queue holds on disk (read records of the current segment included)."""
        return sum(self._sizes.values())

    def __bool__(self) -> bool:
        """Anything left to read."""
        if not self._segments:
            return False
        if self._read_segment < self._segments[-1]:
            return True
        return self._sizes.get(self._read_segment, 0) > self._read_offset

    # -- writing ---------------------------------------------------------------------------------------------
    def append(self, topic: str, payload: builtins.bytes, qos: int, stamp: float) -> None:
        """Keep one record; the oldest segments go when the queue would outgrow ``max_bytes``."""
        name = topic.encode()
        body = _HEAD.pack(_HEAD.size - 4 + len(name) + len(payload), stamp, qos, len(name)) + name + payload
        if len(body) > self.max_bytes:
            self.dropped_full += 1
            return
        if not self._segments or self._sizes[self._segments[-1]] + len(body) > self.segment_bytes:
            self._segments.append(self._segments[-1] + 1 if self._segments else 0)
            self._sizes[self._segments[-1]] = 0
            if len(self._segments) == 1:
                self._read_segment, self._read_offset = self._segments[0], 0
        while self.bytes + len(body) > self.max_bytes and len(self._segments) > 1:
            self._drop_oldest()
        with open(self._path(self._segments[-1]), "ab") as f:
            f.write(body)
        self._sizes[self._segments[-1]] += len(body)

    def _drop_oldest(self) -> None:
        oldest = self._segments.pop(0)
        self._sizes.pop(oldest, None)
        path = self._path(oldest)
        count = sum(1 for _ in self._records(self._read(oldest), self._read_offset if oldest == self._read_segment
                                             else 0))
        self.dropped_full += count
        path.unlink(missing_ok=True)
        if self._read_segment <= oldest:
            self._read_segment, self._read_offset = self._segments[0], 0
        log.warning("disk buffer %s full (%d bytes): dropped %d oldest records", self.name, self.max_bytes, count)

    # -- reading ---------------------------------------------------------------------------------------------
    def _read(self, number: int) -> builtins.bytes:
        """A segment's bytes, read again only when it has grown since (not once per record)."""
        size = self._sizes.get(number, 0)
        if self._cache is None or self._cache[:2] != (number, size):
            try:
                data = self._path(number).read_bytes()
            except OSError:
                data = b""
            self._cache = (number, size, data)
        return self._cache[2]

    @classmethod
    def whole_records(cls, data: builtins.bytes) -> int:
        """How many whole records a segment's bytes hold (a torn or half-written last one is not counted): what a
        tool or a test reads of a disk buffer from outside the bridge."""
        return sum(1 for _ in cls._records(data, 0))

    @staticmethod
    def _records(data: builtins.bytes, offset: int) -> Iterator[tuple[int, Record]]:
        """(offset after the record, record) from ``offset`` on; stops at a torn record."""
        while offset + _HEAD.size <= len(data):
            size, stamp, qos, topic_len = _HEAD.unpack_from(data, offset)
            end = offset + 4 + size
            if end > len(data) or _HEAD.size + topic_len > 4 + size:
                return  # torn: written partly when the bridge died
            start = offset + _HEAD.size
            topic = data[start:start + topic_len].decode(errors="replace")
            yield end, Record(topic, data[start + topic_len:end], qos, stamp)
            offset = end

    def next(self, now: float) -> Record | None:
        """The oldest record not yet read and not older than ``max_age`` (it counts as read); None when empty."""
        while self._segments:
            for end, record in self._records(self._read(self._read_segment), self._read_offset):
                start, self._read_offset = self._read_offset, end
                if now - record.stamp > self.max_age:
                    self.dropped_old += 1
                    continue
                self._unread = (self._read_segment, start)
                return record
            if self._read_segment >= self._segments[-1]:
                return None  # the newest segment: more may be appended
            self._path(self._read_segment).unlink(missing_ok=True)  # finished
            self._segments.remove(self._read_segment)
            self._sizes.pop(self._read_segment, None)
            self._read_segment, self._read_offset = self._segments[0], 0
            self._save_position()
        return None

    def unread(self) -> None:
        """Put back the record :meth:`next` returned last (it could not be sent after all): next() returns it again."""
        if self._unread is not None and self._unread[0] in self._segments:
            self._read_segment, self._read_offset = self._unread
        self._unread = None

    def commit(self) -> None:
        """Remember the read position on disk (at-least-once across restarts)."""
        self._save_position()
