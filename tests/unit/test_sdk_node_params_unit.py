"""Bodies of SDK node parameters, and the SDK's parameter logic, without a broker or ROS."""

from __future__ import annotations

import threading
from types import SimpleNamespace
from typing import Any

import orjson
import pytest

from roslink_mqtt.client.dispatch import CallbackQueue, Scheduler
from roslink_mqtt.client.rclpy.parameters import (
    InvalidParameterValueException,
    NodeParameters,
    Parameter,
    ParameterAlreadyDeclaredException,
    ParameterNotDeclaredException,
    SetParametersResult,
)
from roslink_mqtt.protocol import ProtocolError
from roslink_mqtt.protocol.node_params import (
    DeclaredParameter,
    ParamDeclaration,
    ParamSetRequest,
    ParamSetResult,
    check_node_name,
)
from roslink_mqtt.topics import TopicTree, Verb

CID = "alice-legacy_arm-5f2c9e0a1b3d4c6e"


def test_declaration_round_trip_and_typing() -> None:
    body = ParamDeclaration(CID, {"max_force": DeclaredParameter(2.5, "double", "N"),
                                  "port": DeclaredParameter("/dev/x", "string", read_only=True),
                                  "any": DeclaredParameter(None, "not_set")})
    assert ParamDeclaration.from_json(body.to_json()) == body
    # an integer is a fine double (and becomes one); arrays keep their type
    parsed = ParamDeclaration.from_json(orjson.dumps({"client_id": CID, "parameters": {
        "gain": {"value": 3, "type": "double"}, "ids": {"value": [1, 2], "type": "integer_array"}}}))
    assert parsed.parameters["gain"].value == 3.0 and isinstance(parsed.parameters["gain"].value, float)
    assert parsed.parameters["ids"].value == [1, 2]


@pytest.mark.parametrize(("body", "reason"), [
    ({"parameters": {}}, 'client_id: missing; expected a JSON object {"client_id": …, "parameters": {…}}'),
    ({"client_id": CID, "parameters": []}, "parameters: expected object of at most 256 entries, got an array of 0"),
    ({"client_id": CID, "parameters": {"a": {"value": "x", "type": "double"}}},
     "parameters.a.value: expected double, got string 'x'"),
    ({"client_id": CID, "parameters": {"a": {"value": 1, "type": "float"}}},
     "parameters.a.type: expected one of not_set, bool, integer, double, string, bool_array, integer_array, "
     "double_array, string_array, got \"float\""),
    ({"client_id": CID, "parameters": {"a b": {"value": 1, "type": "integer"}}},
     "parameters: parameter name 'a b' is not a ROS parameter name (letters, digits, underscores, dot-separated "
     "tokens, e.g. 'pid.kp')"),
    ({"client_id": CID, "parameters": {"a": {"value": 1, "type": "integer", "min": 0}}},
     "parameters.a: unknown field 'min' (fields: value, type, description, read_only)"),
    ({"client_id": CID, "parameters": {"a": {"value": 1, "type": "integer", "read_only": "yes"}}},
     'parameters.a.read_only: expected boolean, got "yes"'),
    ({"client_id": CID, "parameters": {}, "extra": 1}, None),
])
def test_declaration_refusals(body: dict, reason: str | None) -> None:
    with pytest.raises(ProtocolError) as err:
        ParamDeclaration.from_json(orjson.dumps(body))
    if reason is not None:
        assert str(err.value) == reason


def test_set_request_and_result() -> None:
    request = ParamSetRequest("turtle1-p3", {"max_force": 3.0}, CID)
    assert ParamSetRequest.from_json(request.to_json()) == request
    result = ParamSetResult("turtle1-p3", False, "too strong", CID)
    assert ParamSetResult.from_json(result.to_json()) == result
    assert ParamSetResult.from_json(b'{"id": "turtle1-p3", "successful": true}').reason == ""
    for bad, reason in ((b'{"id": "x"}', 'successful: missing; expected a JSON object {"id": …, "successful": true}'),
                        (b'{"id": "x", "successful": true, "why": 1}', None),
                        (b'{"id": true, "successful": true}', "id: expected string, 1..128 characters or integer, "
                                                                "got true")):
        with pytest.raises(ProtocolError) as err:
            ParamSetResult.from_json(bad)
        if reason:
            assert str(err.value) == reason


def test_topics_and_node_names() -> None:
    tree = TopicTree()
    assert tree.declare("turtle1", "alice", "legacy_arm") == "roslink/turtle1/from/alice/declare/legacy_arm"
    assert tree.param_set("turtle1", "alice", "legacy_arm") == "roslink/turtle1/to/alice/param_set/legacy_arm"
    parsed = tree.parse("roslink/turtle1/from/alice/param_result/legacy_arm")
    assert parsed.verb is Verb.PARAM_RESULT and parsed.name == "legacy_arm"
    assert Verb.DECLARE.retained_by_sender and Verb.DECLARE.sent_by_user and not Verb.PARAM_SET.sent_by_user
    assert check_node_name("legacy_arm") == "legacy_arm"
    for bad in ("9arm", "arm-1", "arm.x", ""):
        with pytest.raises(ProtocolError):
            check_node_name(bad)


class _Connection:
    def __init__(self) -> None:
        self.on_connected: list[Any] = []
        self.connected = threading.Event()  # never connected: nothing is announced
        self.presence = object()
        self.published: list[tuple[str, bytes]] = []

    def publish(self, topic: str, payload: bytes, qos: int = 1, retain: bool = False) -> Any:
        self.published.append((topic, payload))
        return SimpleNamespace(wait_for_publish=lambda _t: True)

    def on_network_thread(self) -> bool:
        return False


@pytest.fixture
def params() -> Any:
    client = SimpleNamespace(connection=_Connection(), client_id=CID, topics=TopicTree(), username="alice")
    scheduler = Scheduler("test")
    store = NodeParameters("legacy_arm", "turtle1", client, CallbackQueue(), scheduler)
    yield store
    store.withdraw(wait=0)
    scheduler.close()


def test_declare_get_set_with_callbacks(params: NodeParameters) -> None:
    seen: list[list[Parameter]] = []

    def limit(ps: list[Parameter]) -> SetParametersResult:
        seen.append(ps)
        too_big = [p.name for p in ps if p.name == "max_force" and p.value > 5]
        return SetParametersResult(not too_big, "max_force must be at most 5 N" if too_big else "")

    params.add_on_set_callback(limit)
    p = params.declare("max_force", 2.5, {"description": "N"})
    assert (p.name, p.value, p.type_) == ("max_force", 2.5, Parameter.Type.DOUBLE)
    assert seen[-1] == [p]  # rclpy runs the callbacks on declaration too
    with pytest.raises(ParameterAlreadyDeclaredException):
        params.declare("max_force", 1.0)
    results = params.set({"max_force": 9.0})
    assert results == [SetParametersResult(False, "max_force must be at most 5 N")]
    assert params.get("max_force").value == 2.5
    assert params.set([Parameter("max_force", value=4)]) == [SetParametersResult(True, "")]
    assert params.get("max_force").value == 4.0 and params.get("max_force").type_ is Parameter.Type.DOUBLE
    bad = params.set({"max_force": "strong"})[0]
    assert not bad.successful and bad.reason == "parameter 'max_force': expected double, got string 'strong'"
    with pytest.raises(ParameterNotDeclaredException):
        params.get("nope")
    with pytest.raises(ParameterNotDeclaredException):
        params.set({"nope": 1})
    params.declare("port", "/dev/x", {"read_only": True})
    assert params.set({"port": "/dev/y"})[0].reason == "parameter 'port' is read-only"
    dynamic = params.declare("anything")
    assert dynamic.type_ is Parameter.Type.NOT_SET and params.set({"anything": "now a string"})[0].successful
    assert params.get("anything").type_ is Parameter.Type.STRING


def test_a_refusing_callback_refuses_the_declaration(params: NodeParameters) -> None:
    params.add_on_set_callback(lambda ps: SetParametersResult(False, "no"))
    with pytest.raises(InvalidParameterValueException, match="refused: no"):
        params.declare("gain", 1.0)
    assert not params.has("gain")


def test_remote_set_runs_in_the_callback_queue_and_answers(params: NodeParameters) -> None:
    params.add_on_set_callback(lambda ps: SetParametersResult(ps[0].value <= 5, "at most 5"))
    params.declare("max_force", 2.5)
    connection = params.client.connection
    params.on_param_set("turtle1", "legacy_arm", ParamSetRequest("turtle1-p1", {"max_force": 3}, CID).to_json())
    params.on_param_set("turtle1", "legacy_arm", ParamSetRequest("turtle1-p2", {"max_force": 7.0}, CID).to_json())
    params.on_param_set("turtle1", "legacy_arm", ParamSetRequest("turtle1-p3", {"max_force": 1.0}, "other").to_json())
    assert connection.published == []  # nothing runs outside spin
    while params.callbacks.run_once(0.05):
        pass
    answers = [(t, ParamSetResult.from_json(p)) for t, p in connection.published]
    assert [t for t, _ in answers] == ["roslink/turtle1/from/alice/param_result/legacy_arm"] * 2
    assert [(a.id, a.successful, a.reason) for _, a in answers] == [("turtle1-p1", True, ""),
                                                                     ("turtle1-p2", False, "at most 5")]
    assert params.get("max_force").value == 3.0


def test_the_bridge_and_the_sdk_word_a_viewers_refusal_alike() -> None:
    from roslink_mqtt.authorize import refusal
    from roslink_mqtt.config import Role

    assert refusal("bob", Role.VIEWER, Verb.DECLARE, "viewer_arm", robot="turtle1") == (
        "user 'bob' may not declare parameters on turtle1 (as node 'viewer_arm') (operators only): not an operator "
        "of turtle1 (a viewer)")  # the text tests/integration/test_sdk_node_params.py expects from the SDK
    assert refusal("alice", Role.OPERATOR, Verb.DECLARE, "legacy_arm", robot="turtle1") is None
    assert refusal("bob", Role.VIEWER, Verb.PARAM_RESULT, "legacy_arm", robot="turtle1") is not None
