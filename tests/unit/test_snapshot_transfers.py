"""The SDK side of snapshots (client/snapshots.py) with a fake connection: chunks collected by index (a repeat
counts once), a stalled transfer asked again from its first missing chunk, a damaged file refused, a refusal
raised with the robot's reason."""

from __future__ import annotations

import hashlib
import threading

import orjson
import pytest

from roslink_mqtt.client.errors import RobotError, SnapshotError
from roslink_mqtt.client.snapshots import SnapshotTransfers
from roslink_mqtt.protocol.snapshot import SnapshotChunk
from roslink_mqtt.topics import TopicTree, Verb
from tests.support.waits import wait_until

pytestmark = pytest.mark.unit

T = TopicTree()
DATA = bytes(range(256)) * 40  # 10 kB in 4 chunks of 2,560 bytes
PIECES = [DATA[i * 2560:(i + 1) * 2560] for i in range(4)]


class FakeConnection:
    def __init__(self) -> None:
        self.sent: list[tuple[str, dict]] = []
        self.asked = threading.Event()

    def publish(self, topic: str, payload: bytes, qos: int = 0) -> None:
        self.sent.append((topic, orjson.loads(payload)))
        self.asked.set()


def _chunk(index: int, sha: str | None = None) -> bytes:
    return SnapshotChunk(index, 4, len(DATA), sha or hashlib.sha256(DATA).hexdigest(), PIECES[index], 1, 2,
                         9).to_bytes()


def _start(transfers: SnapshotTransfers, **kwargs) -> tuple[threading.Thread, list]:
    out: list = []

    def run() -> None:
        try:
            out.append(transfers.fetch("turtle1", 5.0, **{"timeout": 10.0, "stall": 0.3, **kwargs}))
        except Exception as err:  # noqa: BLE001 - the test reads what was raised
            out.append(err)

    thread = threading.Thread(target=run)
    thread.start()
    return thread, out


def _snapshot_id(connection: FakeConnection) -> str:
    assert connection.asked.wait(5)
    parsed = T.parse(connection.sent[0][0])
    assert parsed is not None and parsed.verb is Verb.SNAPSHOT and parsed.name
    return parsed.name


def test_a_stalled_transfer_resumes_from_its_first_missing_chunk() -> None:
    connection = FakeConnection()
    transfers = SnapshotTransfers(connection, T, "alice", client_id="alice-sdk")  # type: ignore[arg-type]
    thread, out = _start(transfers)
    snapshot_id = _snapshot_id(connection)
    for index in (0, 1, 1, 3):  # chunk 2 lost, chunk 1 twice
        transfers.on_chunk("turtle1", snapshot_id, _chunk(index))
    wait_until("the resume request", lambda: len(connection.sent) >= 2, timeout=5, period=0.01)
    assert connection.sent[1][1] == {"last": 5.0, "resume_from": 2, "client_id": "alice-sdk"}
    transfers.on_chunk("turtle1", snapshot_id, _chunk(2))
    thread.join(5)
    snap = out[0]
    assert snap.data == DATA and snap.messages == 9 and snap.resumes == 1 and snap.chunks == 4


def test_a_damaged_file_and_a_refusal_raise_with_the_reason() -> None:
    connection = FakeConnection()
    transfers = SnapshotTransfers(connection, T, "alice")  # type: ignore[arg-type]
    thread, out = _start(transfers)
    snapshot_id = _snapshot_id(connection)
    for index in range(4):
        transfers.on_chunk("turtle1", snapshot_id, _chunk(index, sha="0" * 64))
    thread.join(5)
    assert isinstance(out[0], SnapshotError) and "arrived damaged" in str(out[0])

    connection = FakeConnection()
    transfers = SnapshotTransfers(connection, T, "bob")  # type: ignore[arg-type]
    thread, out = _start(transfers)
    snapshot_id = _snapshot_id(connection)
    refused = RobotError("turtle1", connection.sent[0][0], "user 'bob' may not ask turtle1 for snapshots")
    assert transfers.on_error(refused)
    thread.join(5)
    assert isinstance(out[0], SnapshotError) and "may not ask turtle1" in str(out[0])
    assert not transfers.on_error(refused)  # that transfer is over
    assert snapshot_id
