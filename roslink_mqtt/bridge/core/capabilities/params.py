"""``param/<node>``: the parameters of the robot's exposed ROS nodes (docs/protocol.md, "Parameters"). ROS-free.

``from/<user>/param/<name>`` ``{"id", "op", …}`` is answered once on ``to/<user>/param_reply/<name>``: get,
list and describe for every granted user; set for operators (and viewers where ``viewers_may_set``), with a live
presence as for commands, and from the holder of the control lease. Refused requests (malformed, not exposed,
not allowed, a value of the wrong type) go to ``to/<user>/error`` with the request's id and never reach ROS;
what ROS answers (or does not: not available, timeout) is the reply. The port (:class:`ParameterPort`,
:mod:`roslink_mqtt.bridge.ros.parameters` with rclpy) talks to the node.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from ....authorize import refusal
from ....config import ParameterRule, Robot, Role
from ....protocol.params import READ_OPS, ParamReply, ParamRequest
from ....topics import TopicTree, Verb
from ..budget import RequestBudget
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring

Publish = Callable[[str, bytes, int], None]


class ParamOutcome(Protocol):
    """How a parameter request ended: ``values`` (the reply), ``error`` (a failed reply), or ``error`` with
    ``refused`` (the node's declared type does not take a value: an error report, as every refusal)."""

    def __call__(self, values: dict[str, Any] | None = None, error: str | None = None, *,
                 refused: bool = False) -> None: ...


class ParameterPort(Protocol):
    """The ROS side of parameter requests."""

    def request(self, rule: ParameterRule, request: ParamRequest, done: ParamOutcome) -> None:
        """Carry out ``request`` on ``rule``'s node; ``done`` is called exactly once (any thread), the rule's
        timeout included."""
        ...


PARAMETER_PORT = PortKey[ParameterPort]("parameters", "ROS nodes' parameters")


class Parameters:
    """The exposed nodes' parameters, read and set on behalf of MQTT users."""

    @classmethod
    def build(cls, wiring: Wiring) -> Parameters:
        """From the bridge's wiring (capabilities/registry.py)."""
        return cls(wiring.robot, wiring.topics, wiring.publish, wiring.ports.get(PARAMETER_PORT), wiring.budget,
                   wiring.report)

    verb = Verb.PARAM

    def __init__(self, robot: Robot, topics: TopicTree, publish: Publish, port: ParameterPort,
                 budget: RequestBudget, report: Report) -> None:
        self.robot, self.topics, self.publish, self.port = robot, topics, publish, port
        self.budget, self.report = budget, report
        self.rules = {rule.name: rule for rule in robot.parameters}

    def parse(self, name: str, payload: bytes) -> ParamRequest:
        return ParamRequest.from_json(payload)

    def gate(self, request: Request[ParamRequest], gates: Gates) -> Refusal | None:
        body, user = request.body, request.user
        assert body is not None
        rule = self.rules.get(request.name)
        if rule is None:
            return Refusal(f"node '{request.name}' does not expose parameters here (parameters: "
                           f"{', '.join(sorted(self.rules)) or 'none'})")
        reading = body.op in READ_OPS
        why = refusal(user, request.role, Verb.PARAM, request.name, robot=self.robot.name,
                      read_only=reading or rule.viewers_may_set)
        if why:
            return Refusal(why)
        if reading:
            return None
        if not gates.is_live(user):
            return Refusal(f"no live operator heartbeat from '{user}': setting parameters needs your presence, "
                           "as commands do")
        if request.role is Role.OPERATOR:  # a set changes the robot: only its driver may
            why = gates.lease_gate(user)
            if why:
                return Refusal(why)
        return None

    def run(self, request: Request[ParamRequest]) -> None:
        body, user = request.body, request.user
        assert body is not None
        if not self.budget.acquire(user):  # bounded: a flood of reads never queues unbounded ROS calls
            self.refuse(request, Refusal(self.budget.refusal(user)))
            return
        reply_topic = self.topics.user_topic(self.robot.name, user, Verb.PARAM_REPLY, request.name)
        answered: list[bool] = []

        def done(values: dict[str, Any] | None = None, error: str | None = None, *, refused: bool = False) -> None:
            if answered:
                return  # exactly once, and the request's slot given back once
            answered.append(True)
            self.budget.release(user)
            if refused:
                self.refuse(request, Refusal(error or "refused"))
                return
            reply = ParamReply(body.id, error is None, values if error is None else None, error,
                               client_id=body.client_id)
            self.publish(reply_topic, reply.to_json(), ParamReply.QOS)

        self.port.request(self.rules[request.name], body, done)

    def refuse(self, request: Request[ParamRequest], refusal: Refusal) -> None:
        body = request.body
        if body is None:
            self.report(request.user, request.topic, refusal.reason, client_id=refusal.client_id,
                        request_id=refusal.request_id)
        else:
            self.report(request.user, request.topic, refusal.reason, client_id=body.client_id, request_id=body.id)


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (Parameters,)
