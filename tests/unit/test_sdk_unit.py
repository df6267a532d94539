"""SDK pieces that are pure logic: typed messages, command streams, robot directory, call correlation, dispatch.

Plus two small network checks that need no robot: a refused wildcard
subscription (a broker that answers SUBACK 0x80) and a refused login.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future

import orjson
import pytest
from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.client import ConnectError, RobotClient, ServiceError, ServiceTimeout
from roslink_mqtt.client.calls import ServiceCalls
from roslink_mqtt.client.commands import CommandStreams, command_leaf
from roslink_mqtt.client.directory import RobotDirectory
from roslink_mqtt.client.dispatch import CallbackQueue, Scheduler
from roslink_mqtt.client.messages import (
    MESSAGE_CLASSES,
    GlobalMotion,
    Image,
    RangeFinderData,
    RoslinkMessage,
    message_class,
    parse_state,
)
from roslink_mqtt.client.rclpy.node import ros_shaped_to_roslink
from roslink_mqtt.client.rclpy.qos import QoSProfile, ReliabilityPolicy, mqtt_qos, qos_profile_sensor_data
from roslink_mqtt.client.subscriptions import parse_state_item
from roslink_mqtt.presence import operator_heartbeat
from roslink_mqtt.protocol import (
    SPECS,
    Envelope,
    MessageId,
    ProtocolError,
    SequenceTracker,
    SystemStatus,
    decode,
    encode,
    encode_message,
)
from roslink_mqtt.topics import TopicTree
from tests.support.refusing_broker import refusing_broker
from tests.support.waits import wait_until

SCAN = {"range_min": 0.1, "range_max": 8.0, "angle_min": -1.0, "angle_max": 1.0, "angle_increment": 1.0,
        "ranges": [1.5, None, 2.0]}


# -- typed messages -------------------------------------------------------------------------
def test_one_frozen_class_per_spec() -> None:
    assert set(MESSAGE_CLASSES) == {spec.name for spec in SPECS}
    for spec in SPECS:
        cls = message_class(int(spec.message_id))
        assert cls is message_class(spec.name) and cls.SPEC is spec and issubclass(cls, RoslinkMessage)
        assert cls.__name__ == "".join(p.capitalize() for p in spec.name.split("_"))
        names = {f.name for f in spec.fields}
        assert names <= set(cls.__dataclass_fields__)
    motion = GlobalMotion(x=1.0, y=2.0, z=0.0, vx=0, vy=0, vz=0, wx=0, wy=0, wz=0, roll=0, pitch=0, yaw=0)
    with pytest.raises(AttributeError):
        motion.x = 3.0  # type: ignore[misc]
    assert hash(motion) == hash(GlobalMotion(**{**motion.payload()}))


def test_state_decodes_to_typed_objects_and_back() -> None:
    data = encode_message(MessageId.RANGE_FINDER_DATA, dict(SCAN), system_id=1, sequence_number=9)
    scan = parse_state(data, robot="turtle1", state_name="range_finder_data")
    assert isinstance(scan, RangeFinderData)
    assert (scan.robot, scan.state_name, scan.system_id, scan.sequence_number) == ("turtle1", "range_finder_data", 1, 9)
    assert scan.ranges == (1.5, None, 2.0) and scan.intensities == ()
    assert scan.payload() == decode(data).payload
    image = parse_state(encode_message(MessageId.IMAGE, {"format": "jpeg", "data": "/9j/"}), robot="r",
                        state_name="front_camera")  # a second preset rule under its own name
    assert isinstance(image, Image) and image.data == b"\xff\xd8\xff" and image.state_name == "front_camera"
    assert Image(format="png", data=b"\x89PNG").payload()["data"] == "iVBORw=="


def test_state_items_typed_generic_or_dropped() -> None:
    assert isinstance(parse_state_item(encode_message(4, dict(SCAN)), "r", "range_finder_data"), RangeFinderData)
    assert parse_state_item(b'{"data": 21.5}', "r", "temperature") == {"data": 21.5}  # a generic rule
    assert parse_state_item(b'{"x": 1}', "r", "global_motion") == {"x": 1}  # not ROSLink: as the JSON it is
    assert parse_state_item(b"not json", "r", "global_motion") is None
    assert parse_state_item(b'{"message_id": 2, "payload": {"x": "far"}}', "r", "global_motion") is None


# -- commands -----------------------------------------------------------------------------
def test_command_leaves() -> None:
    assert command_leaf("twist") == "cmd/twist" and command_leaf("cmd/twist") == "cmd/twist"
    assert command_leaf("/led") == "led" and command_leaf("lights/front") == "lights/front"
    for reserved in ("call/reset", "provide/x", "response/x", "advertise/lights"):
        with pytest.raises(ValueError, match=f"'{reserved.partition('/')[0]}' topic with its own API"):
            command_leaf(reserved)
    with pytest.raises(ValueError):
        command_leaf("cmd/+")


class FakeClock:
    def __init__(self, ms: int) -> None:
        self.ms = ms

    def __call__(self) -> int:
        return self.ms


def test_sequence_numbers_follow_the_clock_per_stream() -> None:
    clock = FakeClock(2**32 - 2)
    streams = CommandStreams(TopicTree(), "alice", clock=clock)
    seqs = [streams.build("turtle1", "twist", {"lx": 0.1})[2] for _ in range(3)]
    assert seqs == [2**32 - 2, 2**32 - 1, 0]  # clock stood still: +1 each, wrapping like the robot expects
    assert streams.build("turtle1", "arm")[2] == 2**32 - 2  # its own stream
    clock.ms = 5000
    assert streams.build("turtle1", "twist")[2] == 5000  # the clock moved on past the counter
    clock.ms = 4000  # NTP stepped the clock back: numbers still grow
    assert streams.build("turtle1", "twist")[2] == 5001
    topic, data, seq = streams.build("turtle1", "go_to_waypoint", {"x": 1, "y": 2})
    env = decode(data, MessageId.GO_TO_WAYPOINT)
    assert topic == "roslink/turtle1/from/alice/cmd/go_to_waypoint" and env.sequence_number == seq
    assert env.payload == {"frame_type": 0, "x": 1, "y": 2, "z": 0.0}


@given(st.lists(st.tuples(st.booleans(), st.integers(1, 50)), min_size=1, max_size=200), st.integers(0, 2**32 - 1))
def test_two_programs_of_one_user_on_one_machine_are_never_dropped(steps, start) -> None:
    """The robot cannot tell two programs of one user apart: a command sent later must count as newer."""
    clock = FakeClock(start)
    programs = {True: CommandStreams(TopicTree(), "alice", clock=clock),
                False: CommandStreams(TopicTree(), "alice", clock=clock)}
    robot = SequenceTracker()
    for use_a, advance_ms in steps:
        clock.ms = (clock.ms + advance_ms) % 2**32
        assert robot.check(("alice", "cmd/twist"), programs[use_a].next_sequence("turtle1", "cmd/twist")).accepted


def test_a_program_with_a_slow_clock_is_heard_once_it_catches_up() -> None:
    ahead, behind = FakeClock(10_000), FakeClock(9_700)  # two machines, clocks 300 ms apart
    a, b = CommandStreams(TopicTree(), "alice", clock=ahead), CommandStreams(TopicTree(), "alice", clock=behind)
    robot = SequenceTracker()
    assert robot.check("s", a.next_sequence("r", "cmd/twist")).accepted
    ahead.ms += 100
    behind.ms += 100
    assert not robot.check("s", b.next_sequence("r", "cmd/twist")).accepted  # looks older than a's last order
    ahead.ms += 301
    behind.ms += 301
    assert robot.check("s", b.next_sequence("r", "cmd/twist")).accepted  # a fell silent: b is newest again


def test_commands_are_validated_before_sending() -> None:
    streams = CommandStreams(TopicTree(), "alice")
    with pytest.raises(ProtocolError, match="unknown field 'lxx'"):
        streams.build("turtle1", "twist", {"lxx": 0.2})
    with pytest.raises(ProtocolError, match="non-finite"):
        streams.build("turtle1", "twist", {"lx": float("nan")})
    topic, data, seq = streams.build("turtle1", "led", {"data": True})  # generic rule: plain JSON, no envelope
    assert (topic, orjson.loads(data), seq) == ("roslink/turtle1/from/alice/led", {"data": True}, None)


def test_ros_shaped_dicts_on_preset_topics() -> None:
    assert ros_shaped_to_roslink("twist", {"linear": {"x": 0.2}, "angular": {"z": 0.5}}) == {
        "lx": 0.2, "ly": 0.0, "lz": 0.0, "ax": 0.0, "ay": 0.0, "az": 0.5}
    assert ros_shaped_to_roslink("twist", {"lx": 0.1}) == {"lx": 0.1}
    assert ros_shaped_to_roslink("go_to_waypoint", {"header": {}, "pose": {"position": {"x": 1, "y": 2}}}) == {
        "x": 1, "y": 2, "z": 0.0}
    assert ros_shaped_to_roslink("arm", {"data": True}) == {}
    with pytest.raises(ValueError):
        ros_shaped_to_roslink("arm", {"data": False})


# -- robots --------------------------------------------------------------------------------
def _heartbeat(status: SystemStatus, session: int = 7) -> bytes:
    payload = {"type": 1, "name": "turtle1", "system_status": int(status), "owner_id": "alice", "mode": 2,
               "session": session}
    return encode(Envelope(MessageId.HEARTBEAT, payload, 1, 3))


def test_directory_online_offline_stale_forgotten() -> None:
    directory = RobotDirectory(stale_after=0.2)
    info = directory.update("turtle1", _heartbeat(SystemStatus.ACTIVE))
    assert info is not None and info.online and info.owner == "alice" and info.session == 7
    assert info.mode.name == "GUIDED" and info.type.name == "GROUND"
    assert not directory.update("turtle1", _heartbeat(SystemStatus.OFFLINE)).online  # the bridge's last-will
    directory.update("turtle1", _heartbeat(SystemStatus.EMERGENCY))
    assert directory.get("turtle1").blocked and directory.get("turtle1").online
    # nothing new: a frozen bridge is not online once stale_after has passed
    wait_until("turtle1 to go stale", lambda: not directory.get("turtle1").online, timeout=5)
    assert directory.update("turtle1", b"garbage") is None and "turtle1" in directory.snapshot()
    directory.update("turtle1", b"")
    assert directory.snapshot() == {}
    threading.Timer(0.1, lambda: directory.update("turtle2", _heartbeat(SystemStatus.ACTIVE))).start()
    assert directory.wait(lambda robots: "turtle2" in robots, timeout=2)
    assert not directory.wait(lambda robots: "turtle3" in robots, timeout=0.1)
    # an operator heartbeat is a ROSLink heartbeat too, but only robots' topics feed the directory
    assert decode(operator_heartbeat("alice", "c1")).message_id == MessageId.HEARTBEAT


# -- service call correlation ------------------------------------------------------------------
class _Wire:
    """Stands in for the Connection: records what would be published."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, dict]] = []

    def publish(self, topic: str, payload: bytes, qos: int = 1, retain: bool = False) -> None:
        self.sent.append((topic, orjson.loads(payload)))


def test_call_correlation_errors_and_timeouts() -> None:
    wire, scheduler = _Wire(), Scheduler()
    calls = ServiceCalls(wire, scheduler, TopicTree(), "alice")  # type: ignore[arg-type]
    try:
        ok = calls.start("turtle1", "reset", {}, timeout=5)
        failed = calls.start("turtle1", "reset", None, timeout=5)
        late = calls.start("turtle1", "slow", {"a": 1}, timeout=0.1)
        (topic, first), (_, second), (_, third) = wire.sent
        assert topic == "roslink/turtle1/from/alice/call/reset" and third["args"] == {"a": 1}
        assert len({first["id"], second["id"], third["id"]}) == 3
        calls.on_reply("turtle1", "reset", orjson.dumps({"id": "someone-else", "result": True, "values": {}}))
        calls.on_reply("turtle1", "reset", b"not json")
        calls.on_reply("turtle1", "reset", orjson.dumps({"id": first["id"], "result": True, "values": {"x": 1}}))
        calls.on_reply("turtle1", "reset", orjson.dumps({"id": second["id"], "result": False, "error": "nope"}))
        assert ok.result(1) == {"x": 1}
        with pytest.raises(ServiceError, match="turtle1/reset: nope") as err:
            failed.result(1)
        assert err.value.reason == "nope" and not isinstance(err.value, ServiceTimeout)
        with pytest.raises(ServiceTimeout, match="no reply within 0.1 s"):
            late.result(2)
        calls.on_reply("turtle1", "slow", orjson.dumps({"id": third["id"], "result": True}))  # too late: ignored
        cancelled = calls.start("turtle1", "reset", {}, timeout=5)
        assert cancelled.cancel() and calls.pending() == 0
        with pytest.raises(TypeError):
            calls.start("turtle1", "reset", [1, 2], timeout=1)  # type: ignore[arg-type]
        open_call = calls.start("turtle1", "reset", {}, timeout=5)
        calls.fail_all("closing")
        with pytest.raises(ServiceError, match="closing"):
            open_call.result(1)
    finally:
        scheduler.close()


# -- dispatch ---------------------------------------------------------------------------------
def test_scheduler_order_cancel_and_callback_errors() -> None:
    scheduler, fired = Scheduler(), []
    try:
        scheduler.call_later(0.06, lambda: fired.append("b"))
        scheduler.call_later(0.02, lambda: fired.append("a"))
        handle = scheduler.call_later(0.04, lambda: fired.append("cancelled"))
        scheduler.call_later(0.01, lambda: 1 / 0)  # logged, the thread goes on
        scheduler.cancel(handle)
        # "b" is the last due: once it ran, the cancelled one (due before) had its turn
        wait_until("'b' fired", lambda: "b" in fired, timeout=5, period=0.01)
        assert fired == ["a", "b"]
    finally:
        scheduler.close()
    queue, ran = CallbackQueue(), []
    queue.put(lambda: 1 / 0)
    queue.put(lambda: ran.append(1))
    assert queue.run_once(0) and queue.run_once(0) and ran == [1]
    assert not queue.run_once(0.01)


# -- network, no robot -----------------------------------------------------------------------------
def test_refused_wildcard_heartbeat_is_handled() -> None:
    with refusing_broker({"roslink/+/heartbeat"}) as (port, subscriptions):
        client = RobotClient("alice", "x", url=f"mqtt://127.0.0.1:{port}", robots=["turtle1"])
        with client:
            assert client.wildcard_heartbeats is False and client.connected
            assert ("roslink/turtle1/heartbeat", True) in subscriptions
            assert ("roslink/turtle1/to/alice/#", True) in subscriptions
            client.watch("turtle2")  # named robots still work
            assert ("roslink/turtle2/heartbeat", True) in subscriptions
            future: Future = client.call_future("turtle1", "reset", timeout=0.2)
            with pytest.raises(ServiceTimeout):
                future.result(2)
        assert not client.connected


def test_unreachable_broker_and_missing_username() -> None:
    from tests.support.net import free_port

    before = threading.active_count()
    for _ in range(3):  # a failed connect leaves no threads behind (callers may retry in a loop)
        with pytest.raises(ConnectError, match="cannot reach the broker"):
            RobotClient("alice", "x", url=f"mqtt://127.0.0.1:{free_port()}").connect(timeout=2)
    wait_until("the failed connects' threads gone", lambda: threading.active_count() <= before, timeout=5)
    with pytest.raises(ValueError, match="no username"):
        RobotClient(None, None)


def test_qos_profiles_map_to_mqtt_qos() -> None:
    assert mqtt_qos(10) is None  # a depth alone keeps the per-command default
    assert mqtt_qos(QoSProfile(depth=1)) == 1 and mqtt_qos(qos_profile_sensor_data) == 0
    assert mqtt_qos(QoSProfile(reliability=ReliabilityPolicy.SYSTEM_DEFAULT)) is None

    class RclpyLike:  # rclpy.qos.QoSProfile, by duck typing: an enum member with a name
        reliability = type("Policy", (), {"name": "BEST_EFFORT"})()
    assert mqtt_qos(RclpyLike()) == 0
    for bad, error in ((-1, ValueError), ("reliable", TypeError), (None, TypeError), (True, TypeError)):
        with pytest.raises(error):
            mqtt_qos(bad)
    with pytest.raises(ValueError, match="depth"):
        QoSProfile(depth=-3)
