"""The bridge's command endpoint, in-process and without ROS: every verb, every refusal, the gates, the sequence rule.

A recording link stands in for MQTT and recording actuators for the ROS side (rosbridge tests a capability
the same way, with a real protocol object). Routes are the demo fleet's real rules with message builders
made of plain Python objects, so nothing here imports rclpy (tests/unit/test_bridge_boundary.py proves the
bridge's core does not). The real bridge still runs in the integration tests
(tests/integration/test_bridge_integration.py).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import orjson
import pytest

from roslink_mqtt.bridge.core.endpoint import MAX_QUEUE_ALLOWANCE, CommandEndpoint
from roslink_mqtt.bridge.core.presets import COMMAND_PRESETS
from roslink_mqtt.bridge.core.routes import Inbound
from roslink_mqtt.config import load_fleet
from roslink_mqtt.presence import operator_heartbeat, operator_signoff
from roslink_mqtt.protocol import SPECS_BY_NAME, AckResult, decode, encode_message
from roslink_mqtt.protocol.control import CallRequest, ErrorReport, Notice
from roslink_mqtt.protocol.lease import ControlState
from roslink_mqtt.topics import Verb
from tests.support.procs import CONFIG

FLEET = load_fleet(CONFIG)
ROBOT = FLEET.robots["turtle1"]
T = FLEET.topics


# -- ROS stand-ins: attribute-shaped like the ROS messages the presets fill -----------------------------
class Vector:
    def __init__(self) -> None:
        self.x = self.y = self.z = 0.0


class Twist:
    def __init__(self) -> None:
        self.linear, self.angular = Vector(), Vector()

    @staticmethod
    def get_fields_and_field_types() -> dict[str, str]:
        return {"linear": "geometry_msgs/Vector3", "angular": "geometry_msgs/Vector3"}


class PoseStamped:
    def __init__(self) -> None:
        self.header = SimpleNamespace(frame_id="")
        self.pose = SimpleNamespace(position=Vector(), orientation=SimpleNamespace(w=0.0))

    @staticmethod
    def get_fields_and_field_types() -> dict[str, str]:
        return {"header": "std_msgs/Header", "pose": "geometry_msgs/Pose"}


class Signal:  # std_msgs/Bool, Float64, String: one ``data`` field
    def __init__(self) -> None:
        self.data: Any = None


class Trigger:  # std_srvs/Trigger, for a service-backed preset
    Request = Signal


def _route(name: str) -> Inbound:
    rule = next(r for r in ROBOT.rules if r.mqtt_topic == name)
    limits = rule.limits or ROBOT.bridge.limits
    if rule.preset is None:  # a generic rule: the ROS JSON as a namespace
        def build_generic(body: Any) -> Any:
            if not isinstance(body, dict) or set(body) - {"data"}:
                from roslink_mqtt.bridge.core.refusals import ConversionError
                raise ConversionError(f"unknown field in {sorted(body)}")
            return SimpleNamespace(**body)
        return Inbound(rule, Signal, None, build_generic, False, limits)
    spec = SPECS_BY_NAME[rule.preset]
    if "/srv/" in rule.ros_type:
        return Inbound(rule, Trigger, spec, lambda _p: Trigger.Request(), False, limits, is_service=True)
    cls = {"twist": Twist, "go_to_waypoint": PoseStamped}.get(rule.preset, Signal)
    build = COMMAND_PRESETS[rule.preset].build
    return Inbound(rule, cls, spec, lambda p: build(p, cls), rule.preset == "twist", limits)


ROUTES = {r.mqtt_topic: _route(r.mqtt_topic) for r in ROBOT.rules if r.direction.value == "mqtt_to_ros"}


@dataclass
class Published:
    topic: str
    payload: bytes
    qos: int
    retain: bool


class RecordingLink:
    def __init__(self) -> None:
        self.connected = threading.Event()
        self.connected.set()
        self.sent: list[Published] = []
        self.acked = True  # the broker acknowledges what is published
        self.delay = 0.0  # what the uplink says a message waits in the network
        self.heard = 0.0  # when the broker's last message arrived (time.monotonic())

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> Any:
        self.sent.append(Published(topic, payload, qos, retain))
        return SimpleNamespace(is_published=lambda: self.acked)

    def queue_delay(self) -> float:
        return self.delay

    def heard_at(self) -> float:
        return self.heard

    def errors(self, user: str) -> list[ErrorReport]:
        return [ErrorReport.from_json(p.payload) for p in self.sent if p.topic == T.error("turtle1", user)]

    def notices(self, user: str) -> list[Notice]:
        return [Notice.from_json(p.payload) for p in self.sent if p.topic == T.notice("turtle1", user)]

    def acks(self) -> list[dict]:
        return [decode(p.payload).payload for p in self.sent if p.topic == T.state("turtle1", "ack")]


@dataclass
class RecordingActuators:
    published: list[tuple[str, str, Any]] = field(default_factory=list)  # (user, route name, message)
    service_calls: list[tuple[str, int | None]] = field(default_factory=list)
    zeros: int = 0
    failsafe_runs: int = 0
    service_ready: bool = True
    goals: dict[str, int] = field(default_factory=dict)  # user -> goals in flight (the action side's table)
    canceled: list[tuple[str | None, str]] = field(default_factory=list)

    def publish(self, user: str, route: Inbound, msg: Any) -> None:
        self.published.append((user, route.name, msg))

    def call_service(self, route: Inbound, request: Any, message_id: int | None, sequence: int | None) -> str | None:
        if not self.service_ready:
            return f"service not available: {route.rule.ros_topic} ({route.rule.ros_type})"
        self.service_calls.append((route.name, sequence))
        return None

    def zero_velocity(self) -> None:
        self.zeros += 1

    def failsafe_actions(self) -> None:
        self.failsafe_runs += 1

    def cancel_goals(self, user: str | None, reason: str) -> int:
        count = sum(n for u, n in self.goals.items() if user is None or u == user)
        self.goals = {u: n for u, n in self.goals.items() if not (user is None or u == user)}
        self.canceled.append((user, reason))
        return count


class Harness:
    def __init__(self) -> None:
        self.link, self.ros = RecordingLink(), RecordingActuators()
        # no capabilities: the verbs' own tests (test_capability_*.py) build the endpoint with theirs
        self.endpoint = CommandEndpoint(FLEET, ROBOT, self.link, self.ros, ROUTES)
        self.endpoint.link_up()
        self.seq = 1000

    def present(self, user: str = "alice", client_id: str = "laptop") -> None:
        self.endpoint.on_mqtt(T.operator(user, client_id), operator_heartbeat(user, client_id))

    def command(self, name: str, payload: dict | None = None, user: str = "alice", *, sequence: int | None = None,
                retained: bool = False, arrived: float | None = None) -> int:
        if sequence is None:
            self.seq += 1
            sequence = self.seq
        body = encode_message(SPECS_BY_NAME[name].message_id, payload or {}, sequence_number=sequence,
                              client_id=f"{user}-prog")
        self.endpoint.on_mqtt(T.command("turtle1", user, name), body, retained, arrived)
        return sequence

    def raw(self, leaf: str, payload: bytes, user: str = "alice", **kwargs: Any) -> None:
        self.endpoint.on_mqtt(T.from_user("turtle1", user, leaf), payload, **kwargs)

    def twists(self) -> list[tuple[float, float]]:
        return [(m.linear.x, m.angular.z) for _, name, m in self.ros.published if name == "cmd/twist"]


@pytest.fixture
def h() -> Harness:
    return Harness()


# -- the link check ----------------------------------------------------------------------------------
@pytest.mark.parametrize(("delay", "allowed"), [(0.0, 0.0), (0.6, 0.6), (30.0, MAX_QUEUE_ALLOWANCE)])
def test_a_busy_uplink_gives_the_heartbeat_its_queue_time_but_a_silent_broker_still_counts(
        h: Harness, delay: float, allowed: float) -> None:
    """A heartbeat held behind data already in the network (a thin uplink) is slow, not lost: its PUBACK may take
    link_timeout + that time, capped, so a frozen broker still stops the robot within link_timeout + the cap."""
    h.link.acked, h.link.delay = False, delay
    sent = time.monotonic()
    h.endpoint.publish_heartbeat()
    timeout = ROBOT.bridge.link_timeout
    h.endpoint.supervise(sent + timeout + allowed - 0.05)
    assert h.endpoint.failsafe.link_up
    h.endpoint.supervise(time.monotonic() + timeout + allowed + 0.05)
    assert not h.endpoint.failsafe.link_up


@pytest.mark.parametrize("heard_for", [0.3, 5.0])
def test_a_busy_downlink_is_slow_not_silent_but_a_broker_that_stops_talking_still_counts(
        h: Harness, heard_for: float) -> None:
    """A viewer's flood through a broker that does not pace him puts the heartbeat's PUBACK behind his messages:
    while the broker's messages keep arriving the link is up, for at most link_timeout + MAX_QUEUE_ALLOWANCE;
    once they stop for link_timeout, the broker is silent."""
    h.link.acked = False
    timeout = ROBOT.bridge.link_timeout
    sent = time.monotonic()
    h.endpoint.publish_heartbeat()
    t = sent + timeout + 0.05
    while t < sent + min(heard_for, timeout + MAX_QUEUE_ALLOWANCE - 0.05):  # messages arrive every 50 ms
        h.link.heard = t - 0.01
        h.endpoint.supervise(t)
        assert h.endpoint.failsafe.link_up, f"stopped {t - sent:.2f} s after the heartbeat while the broker talks"
        t += 0.05
    h.endpoint.supervise(max(t, h.link.heard + timeout + 0.05))
    assert not h.endpoint.failsafe.link_up


# -- commands that go through ----------------------------------------------------------------------
def test_a_twist_from_a_live_operator_reaches_ros_clamped(h: Harness) -> None:
    h.present()
    h.command("twist", {"lx": 0.2, "az": 0.3})
    h.command("twist", {"lx": 99.0})  # over the 0.5 m/s limit: clamped, never refused
    assert h.twists() == [(0.2, 0.3), (ROBOT.bridge.limits.linear, 0.0)]
    assert h.link.errors("alice") == [] and h.endpoint.lease.holder == "alice"


def test_a_clamped_stream_is_told_once_to_its_sender(h: Harness, monkeypatch: pytest.MonkeyPatch) -> None:
    """Clamping is no error (nothing refused), but the sender hears of it: once per stream, on to/<user>/notice."""
    clock = [100.0]
    monkeypatch.setattr(time, "monotonic", lambda: clock[0])  # the arrival times h.command hands over
    monkeypatch.setattr(h.endpoint, "clock", lambda: clock[0])
    h.present()
    first = h.command("twist", {"lx": 50.0})
    for _ in range(5):  # the same stream at 10 Hz: already told
        clock[0] += 0.1
        h.command("twist", {"lx": 50.0})
    [notice] = h.link.notices("alice")
    assert (notice.topic, notice.sequence_number, notice.client_id) == (T.command("turtle1", "alice", "twist"),
                                                                       first, "alice-prog")
    assert "clamped" in notice.notice and "50 m/s cut to 0.5 m/s" in notice.notice
    assert h.link.errors("alice") == []
    clock[0] += 0.1
    h.command("twist", {})  # a zero twist ends the stream; the next one is told again
    h.command("twist", {"az": 9.0})
    clock[0] += ROBOT.bridge.command_timeout + 0.5  # so does a pause longer than the dead-man's
    h.command("twist", {"lx": 0.9})
    assert ["angular speed 9 rad/s" in n.notice for n in h.link.notices("alice")] == [False, True, False]
    assert len(h.link.notices("alice")) == 3
    # another program of alice's, while the first one's stream runs: a stream of its own, told too
    h.endpoint.on_mqtt(T.command("turtle1", "alice", "twist"), encode_message(
        100, {"lx": 0.9}, sequence_number=10_000, client_id="alice-pub2"))  # its own count, above the first one
    assert [n.client_id for n in h.link.notices("alice")][-1] == "alice-pub2"


def test_clamp_notices_forget_ended_streams_beyond_their_bound() -> None:
    from roslink_mqtt.bridge.core.safety import ClampNotices

    notices = ClampNotices(pause=1.0)
    for i in range(ClampNotices.KEPT + 10):  # a program per second, each told once
        assert notices.tell(("alice", f"prog{i}", "twist"), float(i), clamped=True, standstill=False)
    assert len(notices._streams) <= ClampNotices.KEPT
    assert not notices.tell(("alice", f"prog{ClampNotices.KEPT + 9}", "twist"), ClampNotices.KEPT + 9.5,
                            clamped=True, standstill=False)  # the live one is still remembered
    for i in range(3 * ClampNotices.KEPT):  # a flood of live client ids within one pause: still bounded
        notices.tell(("alice", f"flood{i}", "twist"), 1000.0, clamped=True, standstill=False)
        assert len(notices._streams) <= ClampNotices.KEPT + 1


def test_a_generic_rule_carries_ros_json(h: Harness) -> None:
    h.present()
    h.raw("lights", b'{"data": true, "$client_id": "alice-prog"}')
    assert [(name, m.data) for _, name, m in h.ros.published] == [("lights", True)]


def test_a_verb_without_a_capability_is_refused_not_dropped(h: Harness) -> None:
    h.endpoint.on_mqtt(T.call("turtle1", "alice", "reset"), CallRequest("1").to_json())
    assert [e.error for e in h.link.errors("alice")] == ["'call' is not served by this bridge"]


def test_a_service_backed_preset_calls_the_service(h: Harness) -> None:
    h.present()
    seq = h.command("land")
    assert h.ros.service_calls == [("cmd/land", seq)]
    h.ros.service_ready = False
    h.command("land")
    assert [e.error for e in h.link.errors("alice")] == ["service not available: land (std_srvs/srv/Trigger)"]


def test_foreign_topics_and_other_robots_are_ignored(h: Harness) -> None:
    h.present()
    for topic in ("elsewhere/x", T.command("turtle2", "alice", "twist"), T.state("turtle1", "ack"),
                  T.error("turtle1", "alice")):
        h.endpoint.on_mqtt(topic, b"{}")
    assert h.ros.published == [] and h.link.sent == []


# -- every refusal: a reason on the sender's error topic, nothing reaches ROS ------------------------
def _refused(h: Harness, user: str = "alice") -> list[str]:
    assert h.ros.published == [] and h.ros.service_calls == []
    return [e.error for e in h.link.errors(user)]


def test_unknown_command(h: Harness) -> None:
    h.raw("cmd/fly", b"{}")
    assert _refused(h)[0].startswith("no mapping for 'cmd/fly' on robot turtle1 (commands: cmd/arm, ")


def test_retained_commands_are_refused_but_retained_offers_are_not(h: Harness) -> None:
    h.present()
    h.command("twist", {"lx": 0.1}, retained=True)
    h.raw("cmd/twist", b"", retained=True)  # the clearing message itself: silently nothing
    errors = _refused(h)
    assert len(errors) == 1 and errors[0].startswith("ignored a retained command from the broker")
    offer = T.user_topic("turtle1", "alice", Verb.PROVIDE_ACTION, "plan")
    h.endpoint.on_mqtt(offer, b'{"type": "test_msgs/action/Fibonacci"}', True)  # offers are meant to be retained
    assert len(_refused(h)) == 2 and "retained" not in _refused(h)[1]


@pytest.mark.parametrize(("user", "why"), [
    ("bob", "user 'bob' may not send 'cmd/twist' (operators only): not an operator of turtle1 (a viewer)"),
    ("carol", "user 'carol' may not send 'cmd/twist' (operators only): not an operator of turtle1 (no grant)"),
])
def test_viewers_and_strangers_may_not_command(h: Harness, user: str, why: str) -> None:
    h.present(user)
    h.command("twist", {"lx": 0.1}, user=user)
    assert _refused(h, user) == [why]


@pytest.mark.parametrize(("payload", "why"), [
    (b"not json", "not JSON: "),
    (b'{"message_id": 100, "payload": {"lx": "fast"}}', "payload.lx: expected number"),
    (b'{"message_id": 101, "payload": {"frame_type": 0, "x": 1, "y": 2}}',
     "does not match the topic, which expects 100 (twist)"),
])
def test_malformed_bodies_are_refused_with_the_reason(h: Harness, payload: bytes, why: str) -> None:
    h.present()
    h.raw("cmd/twist", payload)
    errors = _refused(h)
    assert len(errors) == 1 and why in errors[0], errors


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_velocity_never_reaches_ros(h: Harness, bad: float) -> None:
    h.present()
    body = orjson.dumps({"message_id": 100, "sequence_number": 5, "payload": {"lx": 0.1}}).replace(
        b"0.1", repr(bad).encode().replace(b"nan", b"NaN").replace(b"inf", b"Infinity"))
    h.raw("cmd/twist", body)
    assert len(_refused(h)) == 1


def test_a_generic_rule_with_a_wrong_field_is_refused(h: Harness) -> None:
    h.present()
    h.raw("lights", b'{"dta": true}')
    assert "unknown field" in _refused(h)[0]


def test_no_presence_no_motion_but_the_number_is_not_used_up(h: Harness) -> None:
    seq = h.command("twist", {"lx": 0.1})
    assert _refused(h)[0].startswith("no live operator heartbeat from 'alice'")
    h.present()
    h.command("twist", {"lx": 0.1}, sequence=seq)  # the same command resent once presence is up
    assert h.twists() == [(0.1, 0.0)]


def test_the_sequence_rule_drops_duplicates_and_stale_numbers(h: Harness) -> None:
    h.present()
    h.command("twist", {"lx": 0.1}, sequence=500)
    h.command("twist", {"lx": 0.2}, sequence=500)
    h.command("twist", {"lx": 0.3}, sequence=499)
    h.command("twist", {"lx": 0.4}, sequence=501)
    assert h.twists() == [(0.1, 0.0), (0.4, 0.0)]
    assert [e.error for e in h.link.errors("alice")] == ["duplicate sequence_number 500 dropped",
                                                         "stale sequence_number 499 dropped"]
    # numbers are per (user, command): another command starts its own count
    h.command("go_to_waypoint", {"frame_type": 0, "x": 1.0, "y": 2.0}, sequence=1)
    assert [name for _, name, _ in h.ros.published][-1] == "cmd/go_to_waypoint"


def test_late_motion_is_dropped_but_a_late_stop_runs(h: Harness) -> None:
    h.present()
    long_ago = time.monotonic() - 10 * ROBOT.bridge.command_timeout
    h.command("twist", {"lx": 0.3}, arrived=long_ago)
    assert "waited" in h.link.errors("alice")[0].error and h.twists() == []
    h.command("twist", {}, arrived=long_ago)
    assert h.twists() == [(0.0, 0.0)]


# -- the motion gates: emergency stop, disarm, arm --------------------------------------------------
def test_an_emergency_stop_needs_no_presence_latches_and_blocks_motion_until_arm(h: Harness) -> None:
    h.command("emergency_stop", {"reason": "test"}, user="alice", sequence=1)
    h.command("emergency_stop", {"reason": "again"}, user="alice", sequence=1)  # never dropped as a duplicate
    assert [name for _, name, _ in h.ros.published] == ["cmd/emergency_stop"] * 2
    assert h.ros.zeros >= 2 and h.endpoint.motion_blocked == "emergency stop by alice"
    assert ROUTES["cmd/emergency_stop"].behaviour.latched
    h.present()
    h.command("twist", {"lx": 0.1})
    h.command("go_to_waypoint", {"frame_type": 0, "x": 1.0, "y": 2.0})
    assert [e.error for e in h.link.errors("alice")] == ["emergency stop by alice: send cmd/arm to resume"] * 2
    h.command("set_mode", {"mode": "GUIDED"})  # not motion: allowed while blocked
    h.command("arm")
    h.command("twist", {"lx": 0.1})
    assert h.endpoint.motion_blocked is None and h.twists() == [(0.1, 0.0)]


def test_state_control_says_blocked_once_per_stop_and_free_again_on_arm(h: Harness) -> None:
    """The e-stop where people look (state/control's ``blocked``), published when motion becomes blocked and when
    it is free again: two viewers taking turns at stops cannot make a stream of retained messages of it."""
    def controls() -> list[ControlState]:
        return [ControlState.from_json(p.payload) for p in h.link.sent if p.topic == T.state("turtle1", "control")]

    before = len(controls())
    for i in range(20):
        h.command("emergency_stop", {"reason": "flood"}, user="bob" if i % 2 else "alice", sequence=i + 1)
    blocked = controls()[before:]
    assert [c.blocked for c in blocked] == ["emergency stop by alice"]
    h.present()
    h.command("arm")  # alice's first command claims the free lease (a change of its own), then frees motion
    assert controls()[-1].blocked == "" and controls()[-1].holder == "alice"


def test_disarm_blocks_motion(h: Harness) -> None:
    h.present()
    h.command("disarm")
    h.command("twist", {"lx": 0.1})
    assert h.link.errors("alice")[0].error == "disarmed by alice: send cmd/arm to resume" and h.twists() == []


def test_preset_behaviour_is_data_on_the_preset() -> None:
    moving = {n for n, p in COMMAND_PRESETS.items() if p.behaviour.moves_robot}
    blocking = {n: p.behaviour.blocks_motion for n, p in COMMAND_PRESETS.items() if p.behaviour.blocks_motion}
    assert moving == {"go_to_waypoint", "takeoff"}
    assert blocking == {"emergency_stop": "emergency stop", "disarm": "disarmed"}
    assert {n for n, p in COMMAND_PRESETS.items() if p.behaviour.never_stale} == {"emergency_stop"}
    assert {n for n, p in COMMAND_PRESETS.items() if p.behaviour.resumes_motion} == {"arm"}


# -- presence and the failsafe ------------------------------------------------------------------------
def _failsafe_acks(h: Harness) -> list[str]:
    return [a["text"] for a in h.link.acks() if a["result"] == AckResult.FAILSAFE]


def test_the_operators_last_will_stops_the_robot_and_says_why(h: Harness) -> None:
    h.present()
    h.command("twist", {"lx": 0.2})
    zeros = h.ros.zeros
    h.endpoint.on_mqtt(T.operator("alice", "laptop"), b"")  # the retained heartbeat cleared by the will
    assert h.ros.zeros > zeros and h.ros.failsafe_runs == 1
    assert _failsafe_acks(h) == ["operator alice went away (last-will)"]


def test_a_signoff_stops_quietly_and_another_users_presence_does_not(h: Harness) -> None:
    h.present()
    h.present("bob", "tablet")
    h.command("twist", {"lx": 0.2})
    h.endpoint.on_mqtt(T.operator("bob", "tablet"), b"")
    assert _failsafe_acks(h) == []
    zeros = h.ros.zeros
    h.endpoint.on_mqtt(T.operator("alice", "laptop"), operator_signoff("alice", "laptop"))
    assert h.ros.zeros > zeros  # stopped all the same
    assert _failsafe_acks(h) == []  # but a program that finished is no failsafe: result 0
    assert [a["text"] for a in h.link.acks() if a["result"] == AckResult.ACCEPTED] == [
        "operator alice went away (signed off)"]


def test_a_zero_twist_is_the_operators_stop_not_a_dead_man_later(h: Harness) -> None:
    h.present()
    h.command("twist", {"lx": 0.2})
    h.command("twist", {"lx": 0.0})  # a released drive pad
    h.endpoint.supervise(time.monotonic() + ROBOT.bridge.command_timeout + 0.5)
    h.endpoint.on_mqtt(T.operator("alice", "laptop"), operator_signoff("alice", "laptop"))
    assert h.link.acks() == []  # no dead-man, and nothing to stop when she signs off


def test_the_dead_man_and_a_lost_broker_stop_the_robot(h: Harness) -> None:
    h.present()
    h.command("twist", {"lx": 0.2})
    h.endpoint.supervise(time.monotonic() + ROBOT.bridge.command_timeout + 0.1)
    assert _failsafe_acks(h)[-1].startswith("no velocity command for")
    h.command("twist", {"lx": 0.2})
    h.endpoint.link_down("connection lost", closing=False)
    assert _failsafe_acks(h)[-1] == "lost the broker (connection lost)"


def test_a_stop_is_repeated_by_supervision(h: Harness) -> None:
    h.present()
    h.command("twist", {"lx": 0.2})
    h.endpoint.on_mqtt(T.operator("alice", "laptop"), b"")
    zeros = h.ros.zeros
    now = time.monotonic()
    for i in range(3):
        h.endpoint.supervise(now + i * 0.05)
    assert h.ros.zeros == zeros + 3


def test_an_oversized_presence_body_is_ignored_and_reported_once(h: Harness) -> None:
    big = operator_heartbeat("alice", "laptop") + b" " * 2000
    for _ in range(3):
        h.endpoint.on_mqtt(T.operator("alice", "laptop"), big)
    errors = h.link.errors("alice")
    assert len(errors) == 1 and "oversized presence payload" in errors[0].error
    assert not h.endpoint.operators.is_live("alice")


def test_refusals_name_the_sender_and_use_the_error_qos(h: Harness) -> None:
    h.command("twist", {"lx": 0.1}, user="alice")  # no presence
    report = h.link.errors("alice")[0]
    sent = next(p for p in h.link.sent if p.topic == T.error("turtle1", "alice"))
    assert (report.client_id, report.message_id, sent.qos, sent.retain) == ("alice-prog", 100, ErrorReport.QOS,
                                                                            False)



@pytest.mark.parametrize(("leaf", "payload"), [
    ("cmd/twist", b'{"message_id": 100, "client_id": "alice-prog", "payload": {"lx": "fast"}}'),  # a bad field
    ("cmd/twist", b'{"client_id": "alice-prog", "lx": 0.1, "speed": 3}'),  # a bare payload with an unknown field
    ("lights", b'{"dta": true, "$client_id": "alice-prog"}'),  # a generic rule's unknown ROS field
])
def test_a_malformed_input_names_its_sender_from_its_one_parse(h: Harness, monkeypatch: pytest.MonkeyPatch,
                                                               leaf: str, payload: bytes) -> None:
    """The refusal is addressed to the program that sent it, from what the parser read: the payload is not
    parsed a second time to find the sender (a flood of malformed input costs one parse each)."""
    import roslink_mqtt.bridge.core.endpoint as endpoint_module

    def second_parse(_payload: bytes) -> str | None:
        raise AssertionError("parsed again for its sender")

    monkeypatch.setattr(endpoint_module, "sender_id", second_parse)
    h.present()
    h.raw(leaf, payload)
    (report,) = h.link.errors("alice")
    assert report.client_id == "alice-prog", report

# -- action goals: the same gates as motion, canceled where velocity stops ---------------------------------
@pytest.mark.parametrize(("end", "whose", "why"), [
    ("last-will", "alice", "operator alice went away (last-will)"),
    ("signoff", "alice", "operator alice went away (signed off)"),
    ("silence", "alice", "operator alice went away (no heartbeat for 1.5 s)"),
    ("broker", None, "lost the broker (connection lost)"),
    ("e-stop", None, "emergency stop by admin"),
])
def test_goals_are_canceled_where_velocity_stops(h: Harness, end: str, whose: str | None, why: str) -> None:
    h.present()
    h.present("admin", "console")
    h.ros.goals = {"alice": 2, "admin": 1}
    if end == "last-will":
        h.endpoint.on_mqtt(T.operator("alice", "laptop"), b"")
    elif end == "signoff":
        h.endpoint.on_mqtt(T.operator("alice", "laptop"), operator_signoff("alice", "laptop"))
    elif end == "silence":  # everyone's presence times out here; alice's goals are canceled with her reason
        h.endpoint.supervise(time.monotonic() + ROBOT.bridge.operator_timeout + 0.1)
    elif end == "broker":
        h.endpoint.link_down("connection lost", closing=False)
    else:
        h.command("emergency_stop", user="admin")
    assert (whose, why) in h.ros.canceled
    count = 2 if whose == "alice" else 3
    assert f"canceled {count} action goal(s){f' of {whose}' if whose else ''}: {why}" in _failsafe_acks(h)


def test_a_flood_of_refused_input_is_reported_at_a_bounded_rate_and_summarised(h: Harness) -> None:
    """A viewer's 500 twists are all refused, but the bridge does not answer each: burst, then a count. (The
    endpoint's clock is the test's: the 500 arrive in one instant, however loaded the machine.)"""
    now = [1000.0]
    h.endpoint.clock = lambda: now[0]
    for _ in range(500):
        h.command("twist", {"lx": 0.1}, user="bob")
    said = _refused(h, "bob")
    assert len(said) == 100  # the burst; the rest held back and counted
    assert not [t for t in h.twists() if t != (0.0, 0.0)]
    now[0] += 0.05  # a token or two back
    h.endpoint.supervise(now[0])
    reports = _refused(h, "bob")
    summary = reports[-1]
    assert len(reports) == len(said) + 1 and summary.startswith("user 'bob' may not send 'cmd/twist'")
    assert f"[{500 - 100} more of your inputs were refused and not reported one by one" in summary
    h.endpoint.clock = time.monotonic
    h.present()
    h.command("twist", {"lx": 0.1})  # alice's refusals are hers: bob used none of them
    h.command("twist", {"lx": 0.1}, user="carol")
    assert [e.error for e in h.link.errors("carol")] and h.twists()[-1] == (0.1, 0.0)
