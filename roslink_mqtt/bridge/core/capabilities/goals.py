"""``goal/<action>`` and ``cancel/<action>``: MQTT users send goals to the robot's ROS actions. ROS-free.

A goal may move the robot: it needs the sender's live presence, motion not blocked (an emergency stop or a
disarm), and, unless the action is open to viewers, the control lease. A cancel needs only the grant: it is how
a user stops what they started. Refusals go on ``to/<user>/error`` with the goal's id and sender and never reach
ROS. The port (:class:`ActionPort`, :mod:`roslink_mqtt.bridge.ros.action_caller` with rclpy) keeps the goals in flight
and reports their status, feedback and result on the user's topics (docs/protocol.md, "Actions").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, TypeVar

from ....authorize import refusal
from ....config import ActionRule, Robot, Role
from ....protocol.goals import GoalCancel, GoalRequest
from ....topics import TopicTree, Verb
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring


class ActionPort(Protocol):
    """The ROS side of action goals."""

    def send_goal(self, user: str, rule: ActionRule, request: GoalRequest) -> str | None:
        """Send ``request`` to ``rule``'s action for ``user``; why not instead (a goal the action type does not
        take, an id already in flight, too many goals)."""
        ...

    def cancel_goal(self, user: str, action: str, goal_id: str) -> str | None:
        """Cancel ``user``'s goal ``goal_id`` on ``action``; why not instead (no such goal of theirs in flight)."""
        ...


ACTION_PORT = PortKey[ActionPort]("actions", "goals sent to the robot's ROS actions")


G = TypeVar("G", bound="_GoalVerb")


class _GoalVerb:
    """What goals and cancels share: the actions, the port, the reports."""

    @classmethod
    def build(cls: type[G], wiring: Wiring) -> G:
        """From the bridge's wiring (capabilities/registry.py)."""
        return cls(wiring.robot, wiring.topics, wiring.ports.get(ACTION_PORT), wiring.report)

    def __init__(self, robot: Robot, topics: TopicTree, port: ActionPort, report: Report) -> None:
        self.robot, self.topics, self.port, self.report = robot, topics, port, report
        self.rules = {rule.name: rule for rule in robot.actions}

    def refuse(self, request: Request[GoalRequest] | Request[GoalCancel], refusal: Refusal) -> None:
        body = request.body
        request_id, client_id = (body.id, body.client_id) if body is not None else \
            (refusal.request_id, refusal.client_id)
        self.report(request.user, request.topic, refusal.reason, client_id=client_id, request_id=request_id)


class SendGoal(_GoalVerb):
    verb = Verb.GOAL
    MOVES_ROBOT = True  # gate and hand-over under the endpoint's motion lock: a stop never slips between them

    def parse(self, name: str, payload: bytes) -> GoalRequest:
        return GoalRequest.from_json(payload)

    def gate(self, request: Request[GoalRequest], gates: Gates) -> Refusal | None:
        user = request.user
        rule = self.rules.get(request.name)
        if rule is None:
            return Refusal(f"unknown action '{request.name}' (actions: {', '.join(sorted(self.rules)) or 'none'})")
        why = refusal(user, request.role, Verb.GOAL, request.name, robot=self.robot.name, read_only=rule.viewers)
        if why:
            return Refusal(why)
        if not gates.is_live(user):
            return Refusal(f"no live operator heartbeat from '{user}': publish a retained heartbeat on "
                           f"{self.topics.operator(user, '<client_id>')} every second")
        blocked = gates.motion_blocked
        if blocked:
            return Refusal(f"{blocked}: send cmd/arm to resume")
        if not rule.viewers and request.role is Role.OPERATOR:  # it moves the robot: only its driver may
            why = gates.lease_gate(user)
            if why:
                return Refusal(why)
        return None

    def run(self, request: Request[GoalRequest]) -> None:
        assert request.body is not None
        why = self.port.send_goal(request.user, self.rules[request.name], request.body)
        if why:
            self.refuse(request, Refusal(why))


class CancelGoal(_GoalVerb):
    verb = Verb.CANCEL

    def parse(self, name: str, payload: bytes) -> GoalCancel:
        return GoalCancel.from_json(payload)

    def gate(self, request: Request[GoalCancel], gates: Gates) -> Refusal | None:
        rule = self.rules.get(request.name)
        if rule is not None:
            why = refusal(request.user, request.role, Verb.CANCEL, request.name, robot=self.robot.name,
                          read_only=rule.viewers)
            if why:
                return Refusal(why)
        return None  # an unknown action has no goal of theirs in flight: the port says so

    def run(self, request: Request[GoalCancel]) -> None:
        assert request.body is not None
        why = self.port.cancel_goal(request.user, request.name, request.body.id)
        if why:
            self.refuse(request, Refusal(why))


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (SendGoal, CancelGoal,)
