"""Every operation is built the same way from the ports the ROS side implements (bridge/core/capabilities/
registry.py): each operation a capability module declares builds from the demo robot's wiring, and every verb a user
sends is served by exactly one operation (``cmd/*`` and ``control/*`` are the endpoint's own: the motion path and the
lease). The walkthrough of docs/architecture.md is walked with a toy operation in a package of its own: its module
alone makes it served, its port's module alone makes the port."""

from __future__ import annotations

import sys
import textwrap
from collections import Counter
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from roslink_mqtt.bridge.core.budget import RequestBudget
from roslink_mqtt.bridge.core.capabilities import (
    ACTION_PORT,
    ACTION_PROVIDER_PORT,
    ADVERTISE_PORT,
    PARAMETER_PORT,
    PROVIDER_PORT,
    ROSOUT_PORT,
    SDK_PARAMETER_PORT,
    SERVICE_PORT,
    VIDEO_PORT,
    Advertise,
    MissingPort,
    Ports,
    Refusal,
    Request,
    Snapshots,
    Watch,
)
from roslink_mqtt.bridge.core.capabilities.registry import OPERATIONS, Wiring, build_all, declared_operations
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.bridge.ros.ports import Supervised, made_ports
from roslink_mqtt.config import load_fleet
from roslink_mqtt.protocol.errors import ProtocolError
from roslink_mqtt.topics import USER_VERBS, Verb
from tests.support.procs import CONFIG
from tests.unit.test_bridge_endpoint import ROUTES, Harness, T

FLEET = load_fleet(CONFIG)


def _wiring(robot: str = "turtle1") -> Wiring:
    port: Any = SimpleNamespace()  # building touches no port: they are used when a request runs
    ports = Ports()
    for key in (SERVICE_PORT, PARAMETER_PORT, ACTION_PORT, ROSOUT_PORT, ADVERTISE_PORT, PROVIDER_PORT,
                ACTION_PROVIDER_PORT, SDK_PARAMETER_PORT, VIDEO_PORT):
        ports.provide(key, port)
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


def test_a_port_is_asked_for_by_its_typed_key_and_a_missing_one_says_which() -> None:
    ports = Ports().provide(ROSOUT_PORT, SimpleNamespace(lines=[]))
    assert ROSOUT_PORT in ports and SERVICE_PORT not in ports and ports.names == ["rosout"]
    assert ports.optional(SERVICE_PORT) is None
    with pytest.raises(MissingPort, match="no port 'services' \\(calls of the robot's ROS services\\)"):
        ports.get(SERVICE_PORT)
    with pytest.raises(ValueError, match="provided twice"):
        ports.provide(ROSOUT_PORT, SimpleNamespace())


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
    _served(h, shout)


# The walkthrough's files, as a package of their own: the capability module (its port, the port's key, ``SERVES``)
# and the ROS module (``MAKES``). Nothing else names the operation.
TOY_CAPABILITY = """
    from typing import Any, Protocol
    from roslink_mqtt.bridge.core.capabilities import PortKey, Refusal, Request
    from roslink_mqtt.topics import Verb


    class MegaphonePort(Protocol):
        def shout(self, user: str, text: str) -> None: ...


    MEGAPHONE_PORT = PortKey[MegaphonePort]("megaphone", "the robot's loudspeaker")


    class Shout:
        verb = Verb.LOG

        def __init__(self, port: MegaphonePort, report: Any) -> None:
            self.port, self.report = port, report

        @classmethod
        def build(cls, wiring: Any) -> "Shout":
            return cls(wiring.ports.get(MEGAPHONE_PORT), wiring.report)

        def parse(self, name: str, payload: bytes) -> str:
            from roslink_mqtt.protocol.errors import ProtocolError
            if not payload:
                raise ProtocolError("nothing to shout")
            return payload.decode()

        def gate(self, request: Request[str], gates: Any) -> Refusal | None:
            return None if gates.role_of(request.user) is not None else Refusal("not granted")

        def run(self, request: Request[str]) -> None:
            self.port.shout(request.user, (request.body or "").upper())

        def refuse(self, request: Request[str], refusal: Refusal) -> None:
            self.report(request.user, request.topic, refusal.reason, payload=request.payload)


    SERVES = (Shout,)
"""
TOY_ROS_SIDE = """
    from roslink_mqtt.bridge.ros.ports import PortMaker
    from toy_ops.capabilities.shout import MEGAPHONE_PORT


    class Loudspeaker:
        def __init__(self, robot: str) -> None:
            self.robot, self.heard, self.ticks = robot, [], 0

        def shout(self, user: str, text: str) -> None:
            self.heard.append((user, text))

        def supervise(self, now: float) -> None:
            self.ticks += 1


    MAKES = (PortMaker(MEGAPHONE_PORT, lambda side: Loudspeaker(side.robot.name)),)
"""


@pytest.fixture
def toy_package(tmp_path: Path) -> Any:
    for folder, module, text in (("capabilities", "shout", TOY_CAPABILITY), ("ros", "loudspeaker", TOY_ROS_SIDE)):
        (tmp_path / "toy_ops" / folder).mkdir(parents=True, exist_ok=True)
        (tmp_path / "toy_ops" / folder / "__init__.py").write_text("")
        (tmp_path / "toy_ops" / folder / f"{module}.py").write_text(textwrap.dedent(text))
    (tmp_path / "toy_ops" / "__init__.py").write_text("")
    sys.path.insert(0, str(tmp_path))
    yield "toy_ops"
    sys.path.remove(str(tmp_path))
    for name in [n for n in sys.modules if n == "toy_ops" or n.startswith("toy_ops.")]:
        del sys.modules[name]


def test_the_walkthrough_a_capability_module_and_a_ros_module_are_all_an_operation_needs(toy_package: str) -> None:
    """What the registry and the ROS side find by themselves: the operation from its module's ``SERVES``, its port
    from its ROS module's ``MAKES``, made from the bridge's side and supervised by the bridge's tick."""
    from roslink_mqtt.bridge.ros.ports import declared_makers

    (operation,) = declared_operations(f"{toy_package}.capabilities")
    (maker,) = declared_makers(f"{toy_package}.ros")
    h = Harness()
    ports = Ports()
    side: Any = SimpleNamespace(robot=FLEET.robots["turtle1"])  # what the bridge hands every maker (RosSide)
    (loudspeaker,) = made_ports(side, ports, makers=[maker])
    assert isinstance(loudspeaker, Supervised)
    wiring = Wiring(FLEET.robots["turtle1"], FLEET.topics, {}, ports, h.endpoint.refuse, lambda t, p: None,
                    lambda t, p, q: None, RequestBudget(8))
    (shout,) = build_all(wiring, operations=(operation,))
    endpoint = CommandEndpoint(FLEET, FLEET.robots["turtle1"], h.link, h.ros, ROUTES, capabilities=[shout])
    endpoint.link_up()
    endpoint.on_mqtt(T.log("turtle1", "alice", "arm_node"), b"hello")
    endpoint.on_mqtt(T.log("turtle1", "alice", "arm_node"), b"")
    loudspeaker.supervise(0.0)
    assert loudspeaker.heard == [("alice", "HELLO")] and loudspeaker.ticks == 1  # type: ignore[attr-defined]
    errors = [p for p in h.link.sent if p.topic == T.error("turtle1", "alice")]
    assert errors and b"nothing to shout" in errors[-1].payload


def test_the_bridge_s_own_modules_declare_every_operation_once() -> None:
    """The registry's scan of bridge/core/capabilities is what the bridge serves: a module dropped from the folder
    or a ``SERVES`` forgotten shows here (and in the verb count above)."""
    assert OPERATIONS == declared_operations()
    assert len(set(OPERATIONS)) == len(OPERATIONS)
    assert {op.verb for op in OPERATIONS} | {Verb.CMD, Verb.CONTROL} == USER_VERBS  # type: ignore[attr-defined]


def _served(h: Any, shout: Any) -> None:
    endpoint = CommandEndpoint(FLEET, FLEET.robots["turtle1"], h.link, h.ros, ROUTES, capabilities=[shout])
    endpoint.link_up()
    endpoint.on_mqtt(T.log("turtle1", "alice", "arm_node"), b"hello")
    endpoint.on_mqtt(T.log("turtle1", "alice", "arm_node"), b"")  # refused by its parser, said on the error topic
    assert isinstance(shout, Shout) and shout.heard == [("alice", "arm_node", "HELLO")]
    errors = [p for p in h.link.sent if p.topic == T.error("turtle1", "alice")]
    assert errors and b"nothing to shout" in errors[-1].payload
