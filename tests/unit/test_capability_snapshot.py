"""Snapshots without ROS: the ring buffer (bridge/core/snapshot_buffer.py) with a clock of the test's own, and the
capability (bridge/core/capabilities/snapshot.py) through the command endpoint with a fake port and a recording uplink.

The buffer holds what its seconds and bytes allow, oldest out first, and its file is an MCAP that the ``mcap`` reader
opens (ros2 profile, a ros2msg schema and a cdr channel per topic). The capability answers an operator with every
chunk in order, each naming the whole file's size and SHA-256; a resume sends from the index asked; a viewer, a
robot without ``snapshot:`` and a malformed request are refused on the error topic with the request's id; a chunk
goes out only when the link has room.
"""

from __future__ import annotations

import hashlib
import io
import threading
from dataclasses import replace

import orjson
import pytest

from roslink_mqtt.bridge.core.capabilities import Snapshots
from roslink_mqtt.bridge.core.capabilities.snapshot import CHUNK
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.bridge.core.snapshot_buffer import SnapshotBuffer, SnapshotFile
from roslink_mqtt.config import SnapshotSettings, SnapshotTopic
from roslink_mqtt.protocol.snapshot import SnapshotChunk
from roslink_mqtt.topics import Verb
from tests.support.waits import never, wait_until
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T

pytestmark = pytest.mark.unit

TOPICS = (SnapshotTopic("odom", "nav_msgs/msg/Odometry"), SnapshotTopic("scan", "sensor_msgs/msg/LaserScan"))
SETTINGS = SnapshotSettings(TOPICS, seconds=10.0, max_bytes=100_000)


class Clock:
    def __init__(self) -> None:
        self.now = 1_700_000_000 * 10**9

    def __call__(self) -> int:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += int(seconds * 1e9)


def _buffer(clock: Clock, settings: SnapshotSettings = SETTINGS) -> SnapshotBuffer:
    return SnapshotBuffer(settings, lambda ros_type: f"# {ros_type}\nint32 x\n", clock)


def test_the_buffer_keeps_its_seconds_and_bytes_oldest_out_first() -> None:
    clock = Clock()
    buffer = _buffer(clock)
    for _ in range(200):  # 20 s at 10 Hz of 100 bytes: only the last 10 s stay
        buffer.add(0, bytes(100))
        clock.advance(0.1)
    messages, held = buffer.held()
    assert 99 <= messages <= 101 and held == 100 * messages
    for _ in range(50):  # 5 kB messages: max_bytes (100 kB) cuts before the seconds do
        buffer.add(1, bytes(5000))
    messages, held = buffer.held()
    assert held <= 100_000 and buffer.dropped_for_size > 0


def test_a_built_snapshot_is_an_mcap_file_of_the_window_asked_for() -> None:
    from mcap.reader import make_reader

    clock = Clock()
    buffer = _buffer(clock)
    for i in range(100):  # odom every 0.1 s for 10 s; scan only in the first 5 s
        buffer.add(0, i.to_bytes(4, "little"))
        if i < 50:
            buffer.add(1, b"scan")
        clock.advance(0.1)
    built = buffer.build(3.0)  # the last 3 s: odom only
    assert built.sha256 == hashlib.sha256(built.data).hexdigest()
    assert built.topics == ("odom",) and 29 <= built.messages <= 31
    reader = make_reader(io.BytesIO(built.data))
    assert reader.get_header().profile == "ros2"
    summary = reader.get_summary()
    assert summary is not None
    assert [(c.topic, c.message_encoding) for c in summary.channels.values()] == [("odom", "cdr")]
    schema = next(iter(summary.schemas.values()))
    assert (schema.name, schema.encoding, schema.data) == ("nav_msgs/msg/Odometry", "ros2msg",
                                                           b"# nav_msgs/msg/Odometry\nint32 x\n")
    times = [m.log_time for _, _, m in reader.iter_messages()]
    assert times == sorted(times) and (built.start, built.end) == (times[0], times[-1])
    assert buffer.build(30.0).topics == ("odom", "scan")
    empty = _buffer(Clock()).build(5.0)
    assert empty.messages == 0 and make_reader(io.BytesIO(empty.data)).get_summary() is not None


class FakePort:
    def __init__(self, size: int) -> None:
        self.data = bytes(range(256)) * (size // 256) + bytes(size % 256)
        self.builds: list[float] = []

    def build(self, last: float) -> SnapshotFile:
        self.builds.append(last)
        return SnapshotFile(self.data, hashlib.sha256(self.data).hexdigest(), 1, 2, 7, ("odom",))


class Lane:
    """A ChunkLink: records chunks; ``full`` holds them back."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, bytes]] = []
        self.full = threading.Event()

    def room(self) -> bool:
        return not self.full.is_set()

    def send(self, topic: str, payload: bytes) -> None:
        self.sent.append((topic, payload))


def _harness(robot=ROBOT, size: int = 5 * CHUNK + 100) -> tuple[Harness, FakePort, Lane, Snapshots]:
    h = Harness()
    port, lane = FakePort(size), Lane()
    snapshots = Snapshots(robot, T, port if robot.snapshot is not None else None, lane, h.endpoint.refuse)
    h.endpoint = CommandEndpoint(FLEET, robot, h.link, h.ros, ROUTES, capabilities=[snapshots])
    h.endpoint.link_up()
    return h, port, lane, snapshots


def _ask(h: Harness, user: str, snapshot_id: str, body: dict | bytes) -> None:
    h.endpoint.on_mqtt(T.user_topic("turtle1", user, Verb.SNAPSHOT, snapshot_id),
                       body if isinstance(body, bytes) else orjson.dumps(body))


def _chunks(lane: Lane, count: int, timeout: float = 5.0) -> list[SnapshotChunk]:
    wait_until(f"{count} chunks", lambda: len(lane.sent) >= count, timeout=timeout, period=0.01)
    return [SnapshotChunk.from_bytes(payload) for _, payload in lane.sent]


def test_an_operator_gets_every_chunk_in_order_and_the_file_checks_out() -> None:
    h, port, lane, snapshots = _harness()
    try:
        _ask(h, "alice", "inc-1", {"last": 12.5, "client_id": "alice-cli"})
        chunks = _chunks(lane, 6)
        assert [c.index for c in chunks] == list(range(6)) and {c.count for c in chunks} == {6}
        assert {topic for topic, _ in lane.sent} == {T.user_topic("turtle1", "alice", Verb.SNAPSHOT_DATA, "inc-1")}
        data = b"".join(c.data for c in chunks)
        assert data == port.data and hashlib.sha256(data).hexdigest() == chunks[0].sha256
        assert chunks[0].size == len(data) and chunks[0].messages == 7 and chunks[0].client_id == "alice-cli"
        assert port.builds == [12.5]
        # a resume: the same id, from chunk 4 on; the file is kept, not built again
        _ask(h, "alice", "inc-1", {"last": 12.5, "resume_from": 4})
        again = _chunks(lane, 8)[6:]
        assert [c.index for c in again] == [4, 5] and port.builds == [12.5]
        assert not h.link.errors("alice")
    finally:
        snapshots.close()


def test_chunks_wait_for_room_on_the_link() -> None:
    h, _port, lane, snapshots = _harness()
    try:
        lane.full.set()
        _ask(h, "alice", "inc-2", {"last": 5})
        never("a chunk handed over while the link is full", lambda: lane.sent, seconds=0.2)
        lane.full.clear()
        assert len(_chunks(lane, 6)) == 6
    finally:
        snapshots.close()


@pytest.mark.parametrize(("user", "body", "words"), [
    ("bob", {"last": 5}, "user 'bob' may not ask turtle1 for snapshots (operators only; it is not open to viewers)"),
    ("alice", {"last": 0}, "last: expected number, 0 < value ≤ 3600"),
    ("alice", {"last": 5, "resume_from": 99}, "resume_from 99: the snapshot has 6 chunks (0 to 5)"),
    ("alice", b"not json", "not JSON: invalid literal"),
])
def test_refusals_name_the_request(user: str, body: dict | bytes, words: str) -> None:
    h, _port, lane, snapshots = _harness()
    try:
        _ask(h, user, "inc-3", body)
        errors = wait_until(f"an error for {user}", lambda: h.link.errors(user), timeout=5, period=0.01)
        assert errors and words in errors[0].error, errors
        assert errors[0].id == "inc-3" and lane.sent == []
    finally:
        snapshots.close()


def test_a_robot_without_snapshots_says_so() -> None:
    h, _port, lane, snapshots = _harness(replace(ROBOT, snapshot=None))
    _ask(h, "alice", "inc-4", {"last": 5})
    errors = h.link.errors("alice")
    assert errors and errors[0].error == "turtle1 keeps no snapshots: its robot file has no `snapshot:` section"
    assert lane.sent == []


def test_one_transfer_per_user_a_flood_of_ids_builds_nothing_more() -> None:
    h, port, lane, snapshots = _harness()
    try:
        lane.full.set()  # the first transfer waits for room on the link
        _ask(h, "alice", "first", {"last": 5})
        wait_until("the first snapshot's build", lambda: port.builds, timeout=5, period=0.01)
        for i in range(20):
            _ask(h, "alice", f"flood-{i}", {"last": 5})
        errors = h.link.errors("alice")
        assert len(errors) == 20 and all("one snapshot at a time: 'first' is still being sent" in e.error
                                         for e in errors)
        assert port.builds == [5.0]
        lane.full.clear()
        assert len(_chunks(lane, 6)) == 6
        def ask_again() -> bool:  # once it is sent, the next one is taken
            _ask(h, "alice", "second", {"last": 5})
            return len(port.builds) == 2
        wait_until("the second snapshot taken", ask_again, timeout=5)
        assert port.builds == [5.0, 5.0]
    finally:
        snapshots.close()
