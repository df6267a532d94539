"""Actions provided by MQTT clients and SDK nodes' parameters as capabilities
(bridge/core/capabilities/provide_action.py, sdk_params.py) through the command endpoint, with recording ports. Real
ones: tests/integration/test_provided_actions.py and test_sdk_node_params.py.
"""

from __future__ import annotations

from collections.abc import Callable

import orjson

from roslink_mqtt.bridge.core.capabilities import (
    DeclareParameters,
    ParameterSetResult,
    ProvideAction,
    UpdateProvidedGoal,
)
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.protocol.node_params import ParamDeclaration, ParamSetResult
from roslink_mqtt.protocol.provided_actions import ActionOffer, ActionUpdate
from roslink_mqtt.topics import Verb
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T


class RecordingPorts:
    def __init__(self) -> None:
        self.events: list[tuple[str, ...]] = []
        self.late: list[Callable[[str], None]] = []

    def offer(self, user: str, name: str, offer: ActionOffer | ParamDeclaration) -> str | None:
        if isinstance(offer, ParamDeclaration):
            self.events.append(("declare", user, name))
            return f"node '{name}' is already declared on turtle1 by carol" if name == "taken" else None
        self.events.append(("offer", user, name, offer.type))
        return None

    def withdraw(self, user: str, name: str, reason: str) -> None:
        self.events.append(("withdraw", user, name))

    def update(self, user: str, name: str, update: ActionUpdate, refused: Callable[[str], None]) -> None:
        self.events.append(("update", user, name, update.status))
        self.late.append(refused)

    def result(self, user: str, node: str, answer: ParamSetResult) -> str | None:
        self.events.append(("result", user, node))
        return None


def harness() -> tuple[Harness, RecordingPorts]:
    h, ports = Harness(), RecordingPorts()
    report = h.endpoint.refuse
    h.endpoint = CommandEndpoint(FLEET, ROBOT, h.link, h.ros, ROUTES, capabilities=[
        ProvideAction("turtle1", ports, report), UpdateProvidedGoal(ports, report),
        DeclareParameters("turtle1", ports, report), ParameterSetResult("turtle1", ports, report)])
    return h, ports


def send(h: Harness, verb: Verb, name: str, body: object, user: str = "alice", retained: bool = False) -> None:
    payload = body if isinstance(body, bytes) else orjson.dumps(body)
    h.endpoint.on_mqtt(T.user_topic("turtle1", user, verb, name), payload, retained=retained)


def test_provided_actions_offer_update_withdraw() -> None:
    h, ports = harness()
    send(h, Verb.PROVIDE_ACTION, "dock", {"type": "test_msgs/action/Fibonacci", "client_id": "pc"}, retained=True)
    send(h, Verb.PROVIDE_ACTION, "dock", {"type": "test_msgs/action/Fibonacci"}, user="bob", retained=True)
    send(h, Verb.ACTION_UPDATE, "dock", {"id": "turtle1-g1", "status": "accepted", "client_id": "pc"})
    ports.late[0]("no goal 'turtle1-g1' waits for you on 'dock'")  # the port finds out later, on the executor
    send(h, Verb.ACTION_UPDATE, "dock", {"id": "turtle1-g2", "status": "flying", "client_id": "pc"})
    send(h, Verb.PROVIDE_ACTION, "dock", b"", retained=True)
    assert ports.events == [("offer", "alice", "dock", "test_msgs/action/Fibonacci"),
                            ("update", "alice", "dock", "accepted"), ("withdraw", "alice", "dock")]
    alice = h.link.errors("alice")
    assert [(e.id, e.client_id) for e in alice] == [("turtle1-g1", "pc"), ("turtle1-g2", "pc")]
    assert "no goal" in alice[0].error and "status: expected one of" in alice[1].error
    assert "operator" in h.link.errors("bob")[0].error


def test_sdk_parameter_declarations_and_results() -> None:
    h, ports = harness()
    declaration = {"client_id": "pc", "parameters": {"gain": {"type": "double", "value": 1.5}}}
    send(h, Verb.DECLARE, "planner", declaration, retained=True)
    send(h, Verb.DECLARE, "taken", declaration, retained=True)
    send(h, Verb.DECLARE, "bad/name", declaration, retained=True)
    send(h, Verb.DECLARE, "planner", declaration, user="bob", retained=True)
    send(h, Verb.PARAM_RESULT, "planner", {"id": "s1", "successful": True, "reason": ""})
    send(h, Verb.PARAM_RESULT, "planner", {"id": "s2", "successful": False, "reason": "x" * 5000, "client_id": "pc"})
    assert ports.events == [("declare", "alice", "planner"), ("declare", "alice", "taken"),
                            ("result", "alice", "planner")]
    alice = h.link.errors("alice")
    assert "already declared" in alice[0].error and alice[0].client_id == "pc"
    assert len(alice) == 3 and "operator" in h.link.errors("bob")[0].error
    # a malformed body's sender is named
    assert "reason: expected string, 0..1024 characters" in alice[2].error and alice[2].client_id == "pc"
