"""Every operation is built the same way from the ports the ROS side implements (bridge/core/capabilities/
registry.py): each registered operation builds from the demo robot's wiring, and every verb a user sends is served
by exactly one operation (``cmd/*`` and ``control/*`` are the endpoint's own: the motion path and the lease)."""

from __future__ import annotations

from collections import Counter
from types import SimpleNamespace
from typing import Any

from roslink_mqtt.bridge.core.budget import RequestBudget
from roslink_mqtt.bridge.core.capabilities import Advertise, Refusal, Request, Snapshots, Watch
from roslink_mqtt.bridge.core.capabilities.registry import OPERATIONS, Ports, Wiring, build_all
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.config import load_fleet
from roslink_mqtt.protocol.errors import ProtocolError
from roslink_mqtt.topics import USER_VERBS, Verb
from tests.support.procs import CONFIG
from tests.unit.test_bridge_endpoint import ROUTES, Harness, T

FLEET = load_fleet(CONFIG)


def _wiring(robot: str = "turtle1") -> Wiring:
    port: Any = SimpleNamespace()  # building touches no port: they are used when a request runs
    ports = Ports(services=port, parameters=port, actions=port, rosout=port, advertise=port, provider=port,
                  action_provider=port, sdk_parameters=port, video=port)
    rule = SimpleNamespace(ros_type="std_msgs/msg/Bool", on_demand=True)
    routes: dict[str, Any] = {"lights": SimpleNamespace(rule=rule), "cmd/twist": SimpleNamespace(
        rule=SimpleNamespace(ros_type="geometry_msgs/msg/Twist", on_demand=False))}
    return Wiring(FLEET.robots[robot], FLEET.topics, routes, ports, lambda *a, **k: None, lambda t, p: None,
                  lambda t, p, q: None, RequestBudget(8))


def test_every_user_verb_is_served_by_exactly_one_operation() -> None:
    verbs = Counter(capability.verb for capability in build_all(_wiring()))
    assert all(count == 1 for count in verbs.values()), verbs
    assert set(verbs) | {Verb.CMD, Verb.CONTROL} == USER_VERBS
    assert len(OPERATIONS) == len(verbs)


def test_each_operation_builds_from_the_wiring_alone() -> None:
    built = {type(capability): capability for capability in build_all(_wiring())}
    advertise = built[Advertise]
    assert isinstance(advertise, Advertise)
    assert advertise.on_demand == {"lights": "std_msgs/msg/Bool"} and advertise.always_there == {"cmd/twist"}
    watch = built[Watch]
    assert isinstance(watch, Watch) and watch.streams == tuple(v.name for v in FLEET.robots["turtle1"].video)
    snapshots = built[Snapshots]
    assert isinstance(snapshots, Snapshots) and snapshots.port is None  # the test wiring keeps no ring buffer



# -- the walkthrough of docs/architecture.md, with a toy operation -----------------------------------------------
class Shout:
    """A toy operation, as the walkthrough adds one: its verb, body, gate, run and refusal, and ``build``. (It takes
    the ``log/*`` verb: a verb is a member of the topic grammar's enum, which a test cannot extend.)"""

    verb = Verb.LOG

    def __init__(self, robot: str, report: Any) -> None:
        self.robot, self.report, self.heard = robot, report, []

    @classmethod
    def build(cls, wiring: Wiring) -> Shout:
        return cls(wiring.robot.name, wiring.report)

    def parse(self, name: str, payload: bytes) -> str:
        text = payload.decode()
        if not text:
            raise ProtocolError("nothing to shout")
        return text

    def gate(self, request: Request[str], gates: Any) -> Refusal | None:
        return None if gates.role_of(request.user) is not None else Refusal("not granted")

    def run(self, request: Request[str]) -> None:
        self.heard.append((request.user, request.name, (request.body or "").upper()))

    def refuse(self, request: Request[str], refusal: Refusal) -> None:
        self.report(request.user, request.topic, refusal.reason, payload=request.payload)


def test_an_operation_added_through_the_registry_alone_is_served_by_the_endpoint() -> None:
    h = Harness()
    wiring = _wiring()
    wiring = Wiring(wiring.robot, wiring.topics, wiring.routes, wiring.ports, h.endpoint.refuse,
                    wiring.publish_reliable, wiring.publish, wiring.budget)
    (shout,) = build_all(wiring, operations=(Shout,))
    endpoint = CommandEndpoint(FLEET, FLEET.robots["turtle1"], h.link, h.ros, ROUTES, capabilities=[shout])
    endpoint.link_up()
    endpoint.on_mqtt(T.log("turtle1", "alice", "arm_node"), b"hello")
    endpoint.on_mqtt(T.log("turtle1", "alice", "arm_node"), b"")  # refused by its parser, said on the error topic
    assert isinstance(shout, Shout) and shout.heard == [("alice", "arm_node", "HELLO")]
    errors = [p for p in h.link.sent if p.topic == T.error("turtle1", "alice")]
    assert errors and b"nothing to shout" in errors[-1].payload
