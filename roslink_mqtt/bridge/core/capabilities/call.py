"""``call/<service>``: MQTT users call the robot's ROS services (docs/protocol.md, "Services"). ROS-free.

``from/<user>/call/<name>`` ``{"id", "args"}`` → ``to/<user>/reply/<name>`` ``{"id", "result", "values" |
"error"}``. Every call is answered exactly once on the reply topic: refused, failed, timed out or done. Only a
refusal by the control lease goes on ``to/<user>/error`` (as every verb's does). The port (:class:`ServicePort`,
implemented with rclpy by :mod:`roslink_mqtt.bridge.ros.service_caller`) converts the arguments, calls, and reports
the outcome; it never blocks the MQTT thread.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from ....authorize import refusal
from ....config import Robot, Role, ServiceRule
from ....protocol.control import CallReply, CallRequest
from ....topics import TopicTree, Verb
from ..budget import RequestBudget
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring

Publish = Callable[[str, bytes], None]
# (values, None) when the service answered, (None, why) when it failed or timed out
Outcome = Callable[[dict[str, Any] | None, str | None], None]


class ServicePort(Protocol):
    """The ROS side of service calls."""

    def call(self, rule: ServiceRule, args: dict[str, Any], done: Outcome) -> str | None:
        """Start a call of ``rule``'s ROS service with ``args`` (its request as JSON); ``done`` is called once
        with the outcome (any thread), the rule's timeout included. Returns why it cannot start now instead
        (bad arguments, no server), and then never calls ``done``."""
        ...


SERVICE_PORT = PortKey[ServicePort]("services", "calls of the robot's ROS services")


def reply(call_id: Any, *, values: dict[str, Any] | None = None, error: str | None = None,
          client_id: str | None = None) -> bytes:
    """A reply body; ``client_id`` repeats the caller's (every program of the user reads the reply topic)."""
    return CallReply(call_id, error is None, values, error, client_id).to_json()


class CallService:
    """The robot's configured services, called on behalf of MQTT users."""

    @classmethod
    def build(cls, wiring: Wiring) -> CallService:
        """From the bridge's wiring (capabilities/registry.py)."""
        return cls(wiring.robot, wiring.topics, wiring.publish_reliable, wiring.ports.get(SERVICE_PORT), wiring.budget,
                   wiring.report)

    verb = Verb.CALL

    def __init__(self, robot: Robot, topics: TopicTree, publish: Publish, port: ServicePort, budget: RequestBudget,
                 report: Report) -> None:
        self.robot, self.topics, self.publish, self.port = robot, topics, publish, port
        self.budget, self.report = budget, report
        self.rules = {rule.name: rule for rule in robot.services}

    def parse(self, name: str, payload: bytes) -> CallRequest:
        return CallRequest.from_json(payload)

    def gate(self, request: Request[CallRequest], gates: Gates) -> Refusal | None:
        rule = self.rules.get(request.name)
        if rule is None:
            known = ", ".join(sorted(self.rules)) or "none"
            return Refusal(f"unknown service '{request.name}' (services: {known})")
        why = refusal(request.user, request.role, Verb.CALL, request.name, robot=self.robot.name,
                      read_only=rule.read_only)
        if why:
            return Refusal(why)
        if request.role is Role.OPERATOR and not rule.read_only:  # it changes the robot: only its driver may
            why = gates.lease_gate(request.user)
            if why:
                return Refusal(why, report=True)
        return None

    def run(self, request: Request[CallRequest]) -> None:
        call, user = request.body, request.user
        assert call is not None
        if not self.budget.acquire(user):
            self.refuse(request, Refusal(self.budget.refusal(user)))
            return
        reply_topic = self.topics.reply(self.robot.name, user, request.name)

        def done(values: dict[str, Any] | None, error: str | None) -> None:
            self.budget.release(user)
            self.publish(reply_topic, reply(call.id, values=values, error=error, client_id=call.client_id))

        why = self.port.call(self.rules[request.name], call.args, done)
        if why:
            self.budget.release(user)
            self.refuse(request, Refusal(why))

    def refuse(self, request: Request[CallRequest], refusal: Refusal) -> None:
        call = request.body
        if refusal.report:
            if call is None:
                self.report(request.user, request.topic, refusal.reason, client_id=refusal.client_id,
                            request_id=refusal.request_id)
            else:
                self.report(request.user, request.topic, refusal.reason, client_id=call.client_id,
                            request_id=None if call.id == "" else call.id)
            return
        call_id, client_id = (call.id, call.client_id) if call is not None else (refusal.request_id, refusal.client_id)
        self.publish(self.topics.reply(self.robot.name, request.user, request.name),
                     reply(call_id, error=refusal.reason, client_id=client_id))


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (CallService,)
