"""The parameter capability (bridge/core/capabilities/params.py) through the command endpoint, with a recording port.

Reads for every granted user, sets only with presence and from the holder of the control lease; every refusal on
the error topic with the request's id and sender (a malformed body's too, read once by its parser); one reply per
request, and its request slot given back once. The real nodes answer in tests/integration/test_parameters.py.
"""

from __future__ import annotations

from typing import Any

import orjson
import pytest

from roslink_mqtt.bridge.core.budget import RequestBudget
from roslink_mqtt.bridge.core.capabilities import Parameters
from roslink_mqtt.bridge.core.capabilities.params import ParamOutcome
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.config import ParameterRule
from roslink_mqtt.protocol.params import ParamReply, ParamRequest
from roslink_mqtt.topics import Verb
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T


class RecordingNodes:
    def __init__(self) -> None:
        self.requests: list[tuple[str, ParamRequest, ParamOutcome]] = []

    def request(self, rule: ParameterRule, request: ParamRequest, done: ParamOutcome) -> None:
        self.requests.append((rule.name, request, done))


@pytest.fixture
def h() -> Harness:
    harness = Harness()
    harness.nodes = RecordingNodes()
    harness.budget = RequestBudget(1)
    params = Parameters(ROBOT, T, lambda topic, payload, qos: harness.link.publish(topic, payload, qos),
                        harness.nodes, harness.budget, harness.endpoint.refuse)
    harness.endpoint = CommandEndpoint(FLEET, ROBOT, harness.link, harness.ros, ROUTES,
                                       capabilities=[params])
    harness.endpoint.link_up()
    return harness


def send(h: Harness, body: Any, user: str = "alice", node: str = "sim_robot") -> None:
    h.endpoint.on_mqtt(T.param("turtle1", user, node), body if isinstance(body, bytes) else orjson.dumps(body))


def replies(h: Harness, user: str = "alice") -> list[ParamReply]:
    topic = T.user_topic("turtle1", user, Verb.PARAM_REPLY, "sim_robot")
    return [ParamReply.from_json(p.payload) for p in h.link.sent if p.topic == topic]


def test_reads_for_everyone_sets_with_presence_and_the_lease(h: Harness) -> None:
    send(h, {"id": 1, "op": "get", "names": ["max_speed"]}, user="bob")  # a viewer reads
    send(h, {"id": 2, "op": "set", "values": {"max_speed": 2.0}, "client_id": "tab"}, user="bob")
    send(h, {"id": 3, "op": "set", "values": {"max_speed": 2.0}})  # alice, no presence yet
    h.present("alice")
    h.present("admin")
    send(h, {"id": 4, "op": "set", "values": {"max_speed": 2.0}})  # claims the free lease
    send(h, {"id": 5, "op": "set", "values": {"max_speed": 3.0}}, user="admin")
    assert [(r.op, r.id) for _, r, _ in h.nodes.requests] == [("get", 1), ("set", 4)]
    assert h.endpoint.lease.holder == "alice"
    bob, alice, admin = h.link.errors("bob"), h.link.errors("alice"), h.link.errors("admin")
    assert [(e.id, e.client_id) for e in bob] == [(2, "tab")] and "operator" in bob[0].error
    assert [e.id for e in alice] == [3] and "presence" in alice[0].error
    assert [e.id for e in admin] == [5] and "control" in admin[0].error
    send(h, {"id": 6, "op": "get", "names": ["max_speed"]})  # alice's one request slot is taken by her set
    assert [e.id for e in h.link.errors("alice")] == [3, 6] and "requests" in h.link.errors("alice")[1].error


def test_one_reply_per_request_and_its_slot_back_once(h: Harness) -> None:
    send(h, {"id": "a", "op": "list"})
    (_, _, done), = h.nodes.requests
    done({"names": ["max_speed"]})
    done(error="timeout: node /sim_robot did not answer within 5 s")  # a late second outcome says nothing
    assert [(r.id, r.result, r.values) for r in replies(h)] == [("a", True, {"names": ["max_speed"]})]
    send(h, {"id": "b", "op": "get", "names": ["x"]})  # the slot came back: not refused for the budget
    h.nodes.requests[-1][2](error="values.x: expected a number, the node declares double", refused=True)
    assert [e.id for e in h.link.errors("alice")] == ["b"]
    send(h, {"id": "c", "op": "describe", "names": ["x"]})
    assert [r.id for _, r, _ in h.nodes.requests] == ["a", "b", "c"]


def test_a_malformed_request_is_reported_with_what_it_said_about_itself(h: Harness) -> None:
    h.present("alice")
    send(h, {"id": 9, "op": "fly", "client_id": "laptop"})
    send(h, b"{not json")
    send(h, {"id": 10, "op": "get", "names": ["x"]}, node="warp")
    (named, anonymous, unknown) = h.link.errors("alice")
    assert (named.id, named.client_id) == (9, "laptop") and "op: expected one of" in named.error
    assert (anonymous.id, anonymous.client_id) == (None, None)
    assert unknown.id == 10 and "node 'warp' does not expose parameters here" in unknown.error
    assert h.nodes.requests == [] and h.endpoint.lease.holder is None  # nothing malformed claims control
