"""The call capability (bridge/core/capabilities/call.py) through the command endpoint, with a recording ServicePort.

Every call is answered exactly once on its reply topic, whatever happens to it; only the control lease refuses on
the error topic; a request slot taken is always given back; a malformed call never claims the control lease.
The real services run in tests/integration/test_services.py.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import orjson
import pytest

from roslink_mqtt.bridge.core.budget import RequestBudget
from roslink_mqtt.bridge.core.capabilities import CallService
from roslink_mqtt.bridge.core.capabilities.call import Outcome
from roslink_mqtt.bridge.core.endpoint import CommandEndpoint
from roslink_mqtt.config import ServiceRule
from roslink_mqtt.protocol.control import CallReply
from tests.unit.test_bridge_endpoint import FLEET, ROBOT, ROUTES, Harness, T

RESET = ROBOT.services[0]  # the demo fleet's reset: changes the robot
STATUS = replace(RESET, name="status", ros_service="status", read_only=True)


class RecordingServices:
    """A ServicePort: remembers each call and lets the test finish it."""

    def __init__(self) -> None:
        self.calls: list[tuple[ServiceRule, dict[str, Any], Outcome]] = []
        self.refuse_with: str | None = None

    def call(self, rule: ServiceRule, args: dict[str, Any], done: Outcome) -> str | None:
        if self.refuse_with:
            return self.refuse_with
        self.calls.append((rule, args, done))
        return None


@pytest.fixture
def h() -> Harness:
    harness = Harness()
    robot = replace(ROBOT, services=(RESET, STATUS))
    harness.services = RecordingServices()
    harness.budget = RequestBudget(2)
    calls = CallService(robot, T, lambda topic, payload: harness.link.publish(topic, payload, 1),
                        harness.services, harness.budget, harness.endpoint.refuse)
    harness.endpoint = CommandEndpoint(FLEET, robot, harness.link, harness.ros, ROUTES,
                                       capabilities=[calls])
    harness.endpoint.link_up()
    return harness


def call(h: Harness, service: str, body: Any, user: str = "alice") -> None:
    h.endpoint.on_mqtt(T.call("turtle1", user, service), body if isinstance(body, bytes) else orjson.dumps(body))


def replies(h: Harness, service: str, user: str = "alice") -> list[CallReply]:
    return [CallReply.from_json(p.payload) for p in h.link.sent if p.topic == T.reply("turtle1", user, service)]


def test_a_call_runs_once_and_its_outcome_is_the_reply(h: Harness) -> None:
    h.present()
    call(h, "reset", {"id": 7, "args": {}, "client_id": "laptop"})
    assert [(rule.name, args) for rule, args, _ in h.services.calls] == [("reset", {})]
    h.services.calls[0][2]({"success": True, "message": ""}, None)
    (reply,) = replies(h, "reset")
    assert (reply.id, reply.result, reply.values["success"], reply.client_id) == (7, True, True, "laptop")


def test_refusals_are_answered_on_the_reply_topic(h: Harness) -> None:
    call(h, "warp", {"id": 1})
    call(h, "reset", {"id": 2}, user="bob")  # a viewer: reset changes the robot
    call(h, "reset", b"[not json", user="alice")
    call(h, "reset", {"id": 3, "args": [1], "client_id": "laptop"}, user="alice")
    answered = [(r.id, r.error or "") for s in ("warp", "reset") for u in ("alice", "bob") for r in replies(h, s, u)]
    # a body that is no JSON has no id to echo; one that names its id has it echoed (read once, by its parser)
    assert [rid for rid, _ in answered] == [1, None, 3, 2]
    assert not any(r.result for s in ("warp", "reset") for u in ("alice", "bob") for r in replies(h, s, u))
    errors = dict(answered[:1] + answered[2:])
    assert errors[1] == "unknown service 'warp' (services: reset, status)"
    assert "operator" in errors[2]
    assert errors[3] == "args: expected object, got an array of 1"
    assert replies(h, "reset")[-1].client_id == "laptop"
    assert h.services.calls == []


def test_a_viewer_may_call_a_read_only_service(h: Harness) -> None:
    call(h, "status", {"id": "s"}, user="bob")
    assert [rule.name for rule, _, _ in h.services.calls] == ["status"]


def test_the_control_lease_refuses_on_the_error_topic_and_a_malformed_call_claims_nothing(h: Harness) -> None:
    h.present("alice")
    h.present("admin")
    call(h, "reset", b"{broken", user="admin")  # malformed: refused before any gate, so it claims no lease
    assert h.endpoint.lease.holder is None
    call(h, "reset", {"id": 1}, user="alice")  # alice claims the free lease
    call(h, "reset", {"id": "x", "client_id": "tablet"}, user="admin")
    assert h.endpoint.lease.holder == "alice"
    (report,) = [e for e in h.link.errors("admin") if "control" in e.error]
    assert (report.id, report.client_id) == ("x", "tablet")
    assert replies(h, "reset", "admin")[-1].id is None  # only the malformed call was answered on its reply topic
    call(h, "status", {"id": 2}, user="admin")  # read-only: no lease needed
    assert [rule.name for rule, _, _ in h.services.calls] == ["reset", "status"]


def test_request_slots_are_always_given_back(h: Harness) -> None:
    h.present()
    call(h, "reset", {"id": 1})
    call(h, "reset", {"id": 2})
    call(h, "reset", {"id": 3})  # over the budget of 2
    assert "requests" in replies(h, "reset")[-1].error
    for _, _, done in h.services.calls:
        done(None, "timeout: no answer within 5 s")
    h.services.refuse_with = "service not available: reset (std_srvs/srv/Trigger) has no server"
    call(h, "reset", {"id": 4})
    call(h, "reset", {"id": 5})
    call(h, "reset", {"id": 6})  # a slot lost on each refusal by the port would have refused this one for budget
    assert [r.error for r in replies(h, "reset")[-3:]] == [h.services.refuse_with] * 3
