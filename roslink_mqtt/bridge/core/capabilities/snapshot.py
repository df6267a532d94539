"""``snapshot/<id>``: the last seconds of the robot's snapshot topics, as MCAP, sent in chunks
(docs/protocol.md, "Snapshots"; protocol/snapshot.py). ROS-free.

``from/<user>/snapshot/<id>`` ``{"last": 30}`` → ``to/<user>/snapshot_data/<id>``, chunk after chunk. Who may ask
is the robot file's ``snapshot.who`` (operators by default); a refusal goes to ``to/<user>/error`` with the id.

One worker thread builds and sends, one snapshot at a time (bounded CPU and memory on the robot): building reads
the ring buffer (the port, :class:`SnapshotPort`), sending hands a chunk to the uplink only when the uplink has
room for it (:class:`ChunkLink`), so chunks go at bulk priority at the pace of the link, never as a queue in front
of motion or state. A finished snapshot is kept a while (:data:`KEEP_FOR`) so a transfer broken by a reconnect
resumes: the same id with ``resume_from``. The failsafe's own snapshots (:meth:`Snapshots.save`) go to the robot's
disk through the same worker.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from ....authorize import refusal
from ....config import Robot
from ....protocol.snapshot import SnapshotChunk, SnapshotRequest
from ....topics import TopicTree, Verb
from ..snapshot_buffer import SnapshotFile
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring

log = logging.getLogger("roslink_mqtt.bridge.snapshot")

CHUNK = 16 * 1024  # bytes of the file per chunk: half a second of a 256 kbit/s uplink
KEEP = 4  # finished snapshots kept for resumed transfers (and at most snapshot.max_bytes of them, the newest always)
KEEP_FOR = 600.0  # s
MAX_WAITING = 8  # requests queued behind the one being served
STALL_LIMIT = 120.0  # s without room on the link before a transfer is given up (the user resumes it)
ROOM_POLL = 0.02  # s between looks at the link while it is full


class SnapshotPort(Protocol):
    """The ROS side: the ring buffer (bridge/core/snapshot_buffer.py, fed by raw ROS subscriptions)."""

    def build(self, last: float) -> SnapshotFile:
        """The last ``last`` seconds as an MCAP file (worker thread; may take a while for a large buffer)."""
        ...


class ChunkLink(Protocol):
    """Where chunks go: the uplink's bulk class (bridge/ros/node.py)."""

    def room(self) -> bool:
        """Whether the next chunk may be handed over now (connected, nothing of the snapshot still waiting)."""
        ...

    def send(self, topic: str, payload: bytes) -> None:
        ...


SNAPSHOT_PORT = PortKey[SnapshotPort]("snapshots", "the ring buffer of the robot's snapshot topics")
CHUNK_PORT = PortKey[ChunkLink]("chunks", "the uplink snapshot chunks leave on")
class FailsafeFilePort(Protocol):
    """Where a failsafe stop's snapshot is kept (the robot's disk)."""

    def __call__(self, built: SnapshotFile, reason: str) -> None: ...


FAILSAFE_FILE_PORT = PortKey[FailsafeFilePort](
    "failsafe_files", "a failsafe stop's snapshot, kept on the robot's disk")


@dataclass(frozen=True, slots=True)
class _Job:
    user: str
    snapshot_id: str
    last: float
    start: int
    client_id: str | None
    topic: str  # where the request came from (for refusals)


class Snapshots:
    """Snapshot requests, served one at a time by a worker thread."""

    @classmethod
    def build(cls, wiring: Wiring) -> Snapshots:
        """From the bridge's wiring (capabilities/registry.py)."""
        ports = wiring.ports  # all three absent on a robot that keeps no ring buffer
        return cls(wiring.robot, wiring.topics, ports.optional(SNAPSHOT_PORT), ports.optional(CHUNK_PORT),
                   wiring.report, save=ports.optional(FAILSAFE_FILE_PORT))

    verb = Verb.SNAPSHOT

    def __init__(self, robot: Robot, topics: TopicTree, port: SnapshotPort | None, link: ChunkLink | None,
                 report: Report, *, save: FailsafeFilePort | None = None) -> None:
        """``port`` and ``link`` are None on a robot without ``snapshot:`` (every request is refused)."""
        self.robot, self.topics, self.port, self.link, self.report = robot, topics, port, link, report
        self.settings = robot.snapshot
        self.settings_bytes = robot.snapshot.max_bytes if robot.snapshot is not None else 0
        self._save = save
        self._jobs: queue.Queue[_Job | tuple[str, float] | None] = queue.Queue()
        self._waiting = 0
        self._lock = threading.Lock()
        self._kept: OrderedDict[tuple[str, str], tuple[float, SnapshotFile]] = OrderedDict()
        self._latest: dict[tuple[str, str], _Job] = {}  # the newest request per transfer (a resume replaces)
        self._stopped = False
        self._thread = threading.Thread(target=self._work, name="snapshots", daemon=True)
        if self.settings is not None and self.port is not None and self.link is not None:
            self._thread.start()
        self.sent_chunks = 0

    # -- Capability ------------------------------------------------------------------------------------------
    def parse(self, name: str, payload: bytes) -> SnapshotRequest:
        return SnapshotRequest.from_json(payload)

    def gate(self, request: Request[SnapshotRequest], gates: Gates) -> Refusal | None:
        if self.settings is None or self.port is None or self.link is None:
            return Refusal(f"{self.robot.name} keeps no snapshots: its robot file has no `snapshot:` section")
        return Refusal(why) if (why := refusal(request.user, request.role, Verb.SNAPSHOT, request.name,
                                               robot=self.robot.name, read_only=self.settings.who == "viewers")) \
            else None

    def run(self, request: Request[SnapshotRequest]) -> None:
        body = request.body
        assert body is not None
        with self._lock:
            other = next((sid for user, sid in self._latest if user == request.user and sid != request.name), None)
            if other is not None:  # one transfer per user: a flood of ids never queues a build per id
                why = (f"one snapshot at a time: '{other}' is still being sent to you (resume it with its id, or "
                       "wait for it)")
            elif self._waiting >= MAX_WAITING:
                why = f"{self.robot.name} is busy with {MAX_WAITING} snapshot requests: ask again shortly"
            else:
                why = None
                self._waiting += 1
                job = _Job(request.user, request.name, body.last, body.resume_from, body.client_id, request.topic)
                self._latest[(job.user, job.snapshot_id)] = job
        if why is not None:
            self.refuse(request, Refusal(why))
            return
        self._jobs.put(job)

    def refuse(self, request: Request[SnapshotRequest], refusal: Refusal) -> None:
        body = request.body
        self.report(request.user, request.topic, refusal.reason,
                    client_id=body.client_id if body is not None else refusal.client_id, request_id=request.name)

    # -- the failsafe's snapshots ----------------------------------------------------------------------------
    def failsafe(self, reason: str) -> None:
        """A failsafe stop happened: keep the seconds before it on the robot's disk (worker thread; never blocks)."""
        if self.settings is not None and self.settings.on_failsafe and self.port is not None and self._save:
            self._jobs.put((reason, self.settings.seconds))

    def close(self) -> None:
        self._stopped = True
        self._jobs.put(None)

    # -- the worker ------------------------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None or self._stopped:
                return
            try:
                if isinstance(job, tuple):
                    self._save_failsafe(*job)
                else:
                    with self._lock:
                        self._waiting -= 1
                    try:
                        self._serve(job)
                    finally:
                        with self._lock:  # however it ended: the user may ask for another
                            if self._latest.get((job.user, job.snapshot_id)) is job:
                                del self._latest[(job.user, job.snapshot_id)]
            except Exception as err:  # noqa: BLE001 - one bad snapshot must not end the worker
                log.exception("snapshot failed: %s", err)
                if isinstance(job, _Job):
                    self.report(job.user, job.topic, f"the snapshot failed on the robot: {err}",
                                client_id=job.client_id, request_id=job.snapshot_id)

    def _save_failsafe(self, reason: str, seconds: float) -> None:
        assert self.port is not None and self._save is not None
        built = self.port.build(seconds)
        self._save(built, reason)

    def _file(self, job: _Job) -> SnapshotFile:
        """The snapshot of ``job``: kept from before (a resume), else built now."""
        key = (job.user, job.snapshot_id)
        now = time.monotonic()
        with self._lock:
            for old in [k for k, (at, _f) in self._kept.items() if now - at > KEEP_FOR]:
                del self._kept[old]
            kept = self._kept.get(key)
        if kept is not None:
            return kept[1]
        assert self.port is not None
        built = self.port.build(job.last)
        with self._lock:
            self._kept[key] = (now, built)
            while len(self._kept) > KEEP or (len(self._kept) > 1 and sum(
                    len(f.data) for _at, f in self._kept.values()) > self.settings_bytes):
                self._kept.popitem(last=False)
        log.info("snapshot %s for %s: %d messages, %d bytes, %s", job.snapshot_id, job.user, built.messages,
                 len(built.data), ", ".join(built.topics) or "no topics")
        return built

    def _serve(self, job: _Job) -> None:
        key, link = (job.user, job.snapshot_id), self.link
        assert link is not None  # the worker runs only with one
        built = self._file(job)
        count = max(1, math.ceil(len(built.data) / CHUNK))
        if job.start >= count:
            self.report(job.user, job.topic, f"resume_from {job.start}: the snapshot has {count} chunks (0 to "
                        f"{count - 1})", client_id=job.client_id, request_id=job.snapshot_id)
            return
        topic = self.topics.user_topic(self.robot.name, job.user, Verb.SNAPSHOT_DATA, job.snapshot_id)
        for index in range(job.start, count):
            waited = time.monotonic()
            while not link.room():
                if self._stopped or self._latest.get(key) is not job:
                    return  # the bridge stops, or the user resumed: that request carries on
                if time.monotonic() - waited > STALL_LIMIT:
                    log.warning("snapshot %s for %s: the link had no room for %.0f s; given up at chunk %d of %d "
                                "(the user may resume it)", job.snapshot_id, job.user, STALL_LIMIT, index, count)
                    return
                time.sleep(ROOM_POLL)
            if self._latest.get(key) is not job:
                return
            piece = built.data[index * CHUNK:(index + 1) * CHUNK]
            link.send(topic, SnapshotChunk(index, count, len(built.data), built.sha256, piece, built.start,
                                                built.end, built.messages, client_id=job.client_id).to_bytes())
            self.sent_chunks += 1


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (Snapshots,)
