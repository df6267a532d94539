"""Snapshots from robots (protocol/snapshot.py): ask, collect the chunks, resume what a reconnect lost, check.

A transfer collects ``to/<user>/snapshot_data/<id>`` chunks by index (a chunk sent twice counts once). When no
chunk came for ``stall`` seconds it asks again with ``resume_from`` the first index missing: the robot keeps a
finished snapshot a while for that. The file is complete when every index is in; it is returned only if its
SHA-256 is the one the robot sent.
"""

from __future__ import annotations

import hashlib
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..protocol.errors import ProtocolError
from ..protocol.snapshot import SnapshotChunk, SnapshotRequest
from ..topics import TopicTree, Verb
from .connection import Connection
from .errors import RobotError, SnapshotError, WaitTimeout

MAX_RESUMES = 20


@dataclass(frozen=True, slots=True)
class Snapshot:
    """A snapshot that arrived whole: the MCAP bytes (written to ``path`` too, when one was given)."""

    robot: str
    snapshot_id: str
    data: bytes
    sha256: str
    messages: int
    start: int  # ns since the epoch, first message
    end: int  # ns, last message
    chunks: int
    resumes: int  # times a stalled transfer was asked again from its first missing chunk
    path: Path | None = None


class _Transfer:
    def __init__(self, robot: str, snapshot_id: str) -> None:
        self.robot, self.snapshot_id = robot, snapshot_id
        self.chunks: dict[int, bytes] = {}
        self.first: SnapshotChunk | None = None
        self.error: str | None = None
        self.changed = threading.Condition()
        self.last_arrival = time.monotonic()

    def missing(self) -> int:
        """The first index not yet in (0 before any chunk)."""
        index = 0
        while index in self.chunks:
            index += 1
        return index

    def complete(self) -> bool:
        return self.first is not None and len(self.chunks) == self.first.count


class SnapshotTransfers:
    """The snapshot transfers of one connection."""

    def __init__(self, connection: Connection, topics: TopicTree, user: str, *, client_id: str | None = None) -> None:
        self.connection, self.topics, self.user, self.client_id = connection, topics, user, client_id
        self._lock = threading.Lock()
        self._active: dict[tuple[str, str], _Transfer] = {}

    def fetch(self, robot: str, last: float, *, timeout: float, stall: float,
              on_progress: Callable[[int, int], None] | None = None) -> Snapshot:
        """Ask ``robot`` for its last ``last`` seconds and wait until the file is whole (see the module)."""
        snapshot_id = f"s{secrets.token_hex(6)}"
        transfer = _Transfer(robot, snapshot_id)
        key = (robot, snapshot_id)
        with self._lock:
            self._active[key] = transfer
        topic = self.topics.user_topic(robot, self.user, Verb.SNAPSHOT, snapshot_id)
        deadline = time.monotonic() + timeout
        resumes = 0
        try:
            self.connection.publish(topic, SnapshotRequest(last, client_id=self.client_id).to_json(),
                                    qos=SnapshotRequest.QOS)
            with transfer.changed:
                while not transfer.complete() and transfer.error is None:
                    now = time.monotonic()
                    if now >= deadline:
                        got = f"{len(transfer.chunks)} of {transfer.first.count} chunks" if transfer.first else \
                            "no chunk"
                        raise WaitTimeout(f"snapshot of {robot}: {got} within {timeout:g} s")
                    if now - transfer.last_arrival >= stall:  # lost to a reconnect, or never sent: ask again
                        resumes += 1
                        if resumes > MAX_RESUMES:
                            raise SnapshotError(robot, snapshot_id, f"stalled {MAX_RESUMES} times; given up")
                        transfer.last_arrival = now
                        request = SnapshotRequest(last, transfer.missing(), client_id=self.client_id)
                        self.connection.publish(topic, request.to_json(), qos=SnapshotRequest.QOS)
                    transfer.changed.wait(min(0.5, max(0.01, deadline - now)))
                    if on_progress is not None and transfer.first is not None:
                        on_progress(len(transfer.chunks), transfer.first.count)
        finally:
            with self._lock:
                self._active.pop(key, None)
        if transfer.error is not None:
            raise SnapshotError(robot, snapshot_id, transfer.error)
        first = transfer.first
        assert first is not None
        data = b"".join(transfer.chunks[i] for i in range(first.count))
        digest = hashlib.sha256(data).hexdigest()
        if len(data) != first.size or digest != first.sha256:
            why = (f"the file arrived damaged ({len(data)} bytes, SHA-256 {digest[:12]}…; the robot sent "
                   f"{first.size}, {first.sha256[:12]}…)")
            raise SnapshotError(robot, snapshot_id, why)
        return Snapshot(robot, snapshot_id, data, digest, first.messages, first.start, first.end, first.count,
                        resumes)

    def on_chunk(self, robot: str, snapshot_id: str, payload: bytes) -> None:
        with self._lock:
            transfer = self._active.get((robot, snapshot_id))
        if transfer is None:
            return  # a late chunk of a transfer that ended
        try:
            chunk = SnapshotChunk.from_bytes(payload)
        except ProtocolError as err:
            with transfer.changed:
                transfer.error = f"a malformed chunk: {err}"
                transfer.changed.notify_all()
            return
        with transfer.changed:
            if transfer.first is None:
                transfer.first = chunk
            elif (chunk.count, chunk.sha256) != (transfer.first.count, transfer.first.sha256):
                transfer.error = "chunks of two different files arrived under one id"
            transfer.chunks[chunk.index] = chunk.data
            transfer.last_arrival = time.monotonic()
            transfer.changed.notify_all()

    def on_error(self, error: RobotError) -> bool:
        """A refusal of one of our snapshot requests; True if it was about one."""
        parsed = self.topics.parse(error.topic)
        if parsed is None or parsed.verb is not Verb.SNAPSHOT:
            return False
        with self._lock:
            transfer = self._active.get((parsed.robot or "", parsed.name or ""))
        if transfer is None:
            return False
        with transfer.changed:
            transfer.error = error.error
            transfer.changed.notify_all()
        return True
