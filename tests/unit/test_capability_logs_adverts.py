"""The log and advertise capabilities (bridge/core/capabilities/logs.py, advertise.py) through the command endpoint,
with recording ports. Real /rosout and on-demand publishers: tests/integration/test_rosout.py, test_on_demand.py.
"""

from __future__ import annotations

from types import SimpleNamespace

import orjson
import pytest

from roslink_mqtt.bridge.core.capabilities import Advertise, LogLines, logs
from roslink_mqtt.bridge.core.capabilities.logs import BURST
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.protocol.rosout import LogLine
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T


class RecordingPorts:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []
        self.adverts: list[tuple[str, str, str | None]] = []

    def publish_log(self, node_name: str, line: LogLine) -> None:
        self.lines.append((node_name, line.msg))

    def advertise(self, user: str, name: str, client_id: str | None) -> None:
        self.adverts.append((user, name, client_id))

    def withdraw(self, user: str, name: str) -> None:
        self.adverts.append((user, name, "withdrawn"))


@pytest.fixture
def h() -> Harness:
    harness = Harness()
    harness.ports = RecordingPorts()
    caps = [LogLines("turtle1", harness.ports, harness.endpoint.refuse),
            Advertise("turtle1", {"lights": "std_msgs/msg/Bool"}, {"twist"}, harness.ports, harness.endpoint.refuse)]
    harness.endpoint = CommandEndpoint(FLEET, ROBOT, harness.link, harness.ros, ROUTES,
                                       capabilities=caps)
    harness.endpoint.link_up()
    return harness


def log(h: Harness, body: object, user: str = "alice") -> None:
    h.endpoint.on_mqtt(T.log("turtle1", user, "planner"), body if isinstance(body, bytes) else orjson.dumps(body))


def advertise(h: Harness, body: object, user: str = "alice", name: str = "lights") -> None:
    payload = body if isinstance(body, bytes) else orjson.dumps(body)
    h.endpoint.on_mqtt(T.advertise("turtle1", user, name), payload, retained=True)


def test_operators_log_viewers_do_not_and_a_flood_is_cut_and_said_once(h: Harness, monkeypatch) -> None:
    clock = [1000.0]  # the bucket's clock stands still during the flood: a slow machine refilled it mid-burst
    monkeypatch.setattr(logs, "time", SimpleNamespace(monotonic=lambda: clock[0]))
    log(h, {"level": 20, "msg": "hello"})
    log(h, {"level": 20, "msg": "from a viewer", "client_id": "phone"}, user="bob")
    log(h, {"level": 7, "msg": "bad level", "client_id": "laptop"})
    assert h.ports.lines == [("planner", "hello")]
    assert h.link.errors("bob")[0].client_id == "phone" and "operator" in h.link.errors("bob")[0].error
    assert h.link.errors("alice")[0].client_id == "laptop" and "level" in h.link.errors("alice")[0].error
    for i in range(BURST + 50):
        log(h, {"level": 20, "msg": f"{i}"})
    assert len(h.ports.lines) == BURST  # "hello" took one token: BURST - 1 of the flood pass
    dropped = [e for e in h.link.errors("alice") if "dropped" in e.error]
    assert len(dropped) == 1  # told once per episode
    clock[0] += 1.0  # a second later: a new episode, lines pass again and a new flood is said again
    log(h, {"level": 20, "msg": "after"})
    assert h.ports.lines[-1] == ("planner", "after")
    for i in range(BURST + 10):
        log(h, {"level": 20, "msg": f"again {i}"})
    assert len([e for e in h.link.errors("alice") if "dropped" in e.error]) == 2


def test_advertisements_come_and_go_and_are_checked(h: Harness) -> None:
    advertise(h, {"type": "std_msgs/msg/Bool", "client_id": "laptop"})
    advertise(h, {"type": "std_msgs/msg/Bool"})
    advertise(h, b"")  # withdrawn
    advertise(h, {"type": "std_msgs/msg/String", "client_id": "laptop"})
    advertise(h, {"type": "std_msgs/msg/Bool"}, user="bob")
    advertise(h, {"type": "geometry_msgs/msg/Twist"}, name="twist")  # always there: nothing to do, no error
    advertise(h, {"type": 5}, name="twist")  # whatever it says
    advertise(h, {"type": "std_msgs/msg/Bool"}, name="warp")
    assert h.ports.adverts == [("alice", "lights", "laptop"), ("alice", "lights", None),
                               ("alice", "lights", "withdrawn")]
    alice = h.link.errors("alice")
    assert [e.client_id for e in alice] == ["laptop", None]
    assert "carries std_msgs/msg/Bool, not std_msgs/msg/String" in alice[0].error
    assert "no mapping 'warp'" in alice[1].error and "operator" in h.link.errors("bob")[0].error


class RecordingProvider:
    def __init__(self) -> None:
        self.events: list[tuple[str, ...]] = []

    def offer(self, user: str, name: str, offer: object) -> str | None:
        self.events.append(("offer", user, name))
        return "service 'plan' is already provided by carol" if name == "taken" else None

    def withdraw(self, user: str, name: str, reason: str) -> None:
        self.events.append(("withdraw", user, name, reason))

    def respond(self, user: str, name: str, answer: object) -> str | None:
        self.events.append(("respond", user, name))
        return f"no pending request with id 'x' for '{name}'"


def test_offers_withdrawals_and_responses_of_provided_services() -> None:
    from roslink_mqtt.bridge.core.capabilities import ProvideService, RespondToCall

    h = Harness()
    port = RecordingProvider()
    h.endpoint = CommandEndpoint(FLEET, ROBOT, h.link, h.ros, ROUTES,
                                 capabilities=[ProvideService("turtle1", port, h.endpoint.refuse),
                                               RespondToCall(port, h.endpoint.refuse)])
    offer = orjson.dumps({"type": "std_srvs/srv/Trigger", "client_id": "laptop"})
    h.endpoint.on_mqtt(T.provide("turtle1", "alice", "plan"), offer, retained=True)
    h.endpoint.on_mqtt(T.provide("turtle1", "alice", "taken"), offer, retained=True)
    h.endpoint.on_mqtt(T.provide("turtle1", "bob", "plan"), offer, retained=True)  # a viewer may not provide
    h.endpoint.on_mqtt(T.provide("turtle1", "alice", "plan"), b"", retained=True)
    h.endpoint.on_mqtt(T.provide("turtle1", "alice", "plan"), b'{"type": "std_srvs/Trigger", "client_id": "pc"}')
    h.endpoint.on_mqtt(T.response("turtle1", "alice", "plan"), b'{"id": "x", "result": true, "client_id": "pc"}')
    assert port.events == [("offer", "alice", "plan"), ("offer", "alice", "taken"),
                           ("withdraw", "alice", "plan", "withdrawn by the provider"), ("respond", "alice", "plan")]
    alice = h.link.errors("alice")
    assert [e.client_id for e in alice] == ["laptop", "pc", "pc"]
    assert "already provided by carol" in alice[0].error and "not a service type" in alice[1].error
    assert "no pending request" in alice[2].error and "operator" in h.link.errors("bob")[0].error
