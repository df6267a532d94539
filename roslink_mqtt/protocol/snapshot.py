"""On-robot snapshots (docs/protocol.md, "Snapshots"): the last seconds of chosen ROS topics, as MCAP, on request.

The bridge keeps the robot file's ``snapshot.topics`` in a ring buffer (CDR, as ``ros2 bag`` records them). A user
sends ``from/<user>/snapshot/<id>`` ``{"last": 30}``; the bridge writes the last ``last`` seconds as an MCAP file
and sends it on ``to/<user>/snapshot_data/<id>`` in chunks, at bulk priority (after motion and state, never in
front of a heartbeat or a pose). Each chunk is a :class:`SnapshotChunk`: a JSON header line, then the chunk's bytes.
A chunk lost to a reconnect is asked for again with the same id and ``resume_from`` (the first index missing): the
bridge keeps a finished snapshot a while for that. ``sha256`` (of the whole file, in every header) tells the
receiver its file is the bridge's. A refusal (not allowed, no snapshot topics, a malformed request) comes on
``to/<user>/error`` with the request's id.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..topics import TopicTree, Verb
from .body import SENDER, BodyField, Integer, Number, Text, read, split_header, write
from .errors import ProtocolError

MAX_LAST = 3600.0  # s: more than any ring buffer holds
MAX_CHUNKS = 1 << 20
_DOC, _R, _U = TopicTree(), "<robot>", "<user>"


@dataclass(frozen=True, slots=True)
class SnapshotRequest:
    """Ask for a snapshot, on ``from/<user>/snapshot/<id>`` (read by the bridge)."""

    last: float
    resume_from: int = 0
    client_id: str | None = None

    FIELDS = (
        BodyField("last", Number(0, MAX_LAST, low_open=True), True,
                  "seconds before now to include (the ring buffer holds `snapshot.seconds`; more gives what it has)"),
        BodyField("resume_from", Integer(0, MAX_CHUNKS), False,
                  "send the chunks from this index on (a resumed transfer: same id, the first index missing)", 0,
                  written="nonempty"),
        BodyField("client_id", SENDER, False, "the sender's id, repeated in the chunks", None, names="sender"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # resume_from 0 (from the start) is left out
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> SnapshotRequest:
        return cls(**read(cls.FIELDS, data, shape='expected a JSON object {"last": 30}'))


@dataclass(frozen=True, slots=True)
class SnapshotChunk:
    """One piece of a snapshot, on ``to/<user>/snapshot_data/<id>``: a JSON header line, then ``data``."""

    index: int
    count: int
    size: int  # bytes of the whole file
    sha256: str  # of the whole file, hex
    data: bytes
    start: int = 0  # ns: the first message in the file
    end: int = 0  # ns: the last one
    messages: int = 0
    client_id: str | None = None

    FIELDS = (
        BodyField("index", Integer(0, MAX_CHUNKS), True, "this chunk's place, from 0"),
        BodyField("count", Integer(1, MAX_CHUNKS), True, "how many chunks the file has"),
        BodyField("size", Integer(0), True, "bytes of the whole file"),
        BodyField("sha256", Text(64), True, "SHA-256 of the whole file, hex: check it when every chunk is in"),
        BodyField("start", Integer(0), False, "ns since the epoch: the first message in the file", 0),
        BodyField("end", Integer(0), False, "ns since the epoch: the last message in the file", 0),
        BodyField("messages", Integer(0), False, "messages in the file", 0),
        BodyField("client_id", Text(), False, "the request's `client_id`, when it had one", None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        """The header line (the bytes follow it: :meth:`to_bytes`)."""
        return write(self.FIELDS, self)

    def to_bytes(self) -> bytes:
        return self.to_json() + b"\n" + self.data

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> SnapshotChunk:
        """A chunk from its header line alone (``data`` empty)."""
        got = read(cls.FIELDS, data, shape="snapshot chunk: expected a JSON object", strict=False,
                   what="snapshot chunk")
        if got["index"] >= got["count"]:
            raise ProtocolError(f"snapshot chunk: index {got['index']} of {got['count']}")
        return cls(data=b"", **got)

    @classmethod
    def from_bytes(cls, payload: bytes) -> SnapshotChunk:
        """A chunk as the bridge sends it: the header line, a newline, the bytes."""
        line, data = split_header(payload, "snapshot chunk", "the data")
        return replace(cls.from_json(line), data=data)

SNAPSHOT_BODIES: tuple[tuple[str, str, type], ...] = (
    ("snapshot request", f"`{_DOC.user_topic(_R, _U, Verb.SNAPSHOT, '<id>')}`", SnapshotRequest),
    ("snapshot chunk", f"`{_DOC.user_topic(_R, _U, Verb.SNAPSHOT_DATA, '<id>')}`: this JSON header line, a newline, "
                       "then the chunk's bytes", SnapshotChunk),
)
