"""``control/claim|release|take_over``: who drives the robot (the control lease). ROS-free.

The lease itself is :class:`~roslink_mqtt.bridge.core.lease.ControlLease` (pure decisions); its port is the command
endpoint's motion state (:class:`LeaseDesk`), because a take-over stops the robot under the same lock as every
command. Refusals go on ``to/<user>/error``; every change of holder on retained ``state/control``.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Protocol

from ....authorize import refusal
from ....config import Role
from ....protocol.lease import ControlOp, read_request
from ....topics import Verb
from ..lease import ControlLease, Outcome
from .base import Gates, Refusal, Report, Request

log = logging.getLogger("roslink_mqtt.bridge")


@dataclass(frozen=True, slots=True)
class ControlBody:
    op: ControlOp
    client_id: str | None  # the requesting program's, for the reports


class LeaseDesk(Protocol):
    """The endpoint's motion state, as the lease verbs need it."""

    lock: threading.RLock
    lease: ControlLease

    def is_live(self, user: str) -> bool: ...

    def trigger_stop(self, reason: str, level: int = logging.WARNING) -> None:
        """Stop the robot now (zero velocity, acknowledged on state/ack)."""
        ...

    def publish_control(self) -> None:
        """Retained ``state/control``: the lease as it is now."""
        ...

    def tell_displaced(self, user: str, text: str) -> None:
        """Say on ``user``'s error topic that control was taken from them."""
        ...

    def cancel_goals(self, user: str | None, why: str) -> None:
        """Cancel ``user``'s action goals (said on state/ack)."""
        ...


class Control:
    """The lease verbs of one robot."""

    verb = Verb.CONTROL

    def __init__(self, robot: str, desk: LeaseDesk, report: Report) -> None:
        self.robot, self.desk, self.report = robot, desk, report

    def parse(self, name: str, payload: bytes) -> ControlBody:
        op = ControlOp.parse(name)
        return ControlBody(op, read_request(payload))

    def gate(self, request: Request[ControlBody], gates: Gates) -> Refusal | None:
        if request.role is not Role.OPERATOR:
            return Refusal(refusal(request.user, request.role, Verb.CONTROL, request.name, robot=self.robot) or "",
                           report=True)
        return None  # whether the lease grants it is the request's outcome, decided under the lock in run()

    def run(self, request: Request[ControlBody]) -> None:
        assert request.body is not None
        user, desk = request.user, self.desk
        with desk.lock:
            answer = desk.lease.request(user, request.body.op, live=desk.is_live(user), now=time.time())
            if answer.outcome is Outcome.REFUSED:
                self.refuse(request, Refusal(answer.reason, report=True))
                return
            log.info("%s: %s", self.robot, answer.reason)
            if answer.outcome is Outcome.TAKEN and answer.displaced is not None:
                # the new holder starts from standstill; the old one hears it at once, on its error topic
                desk.trigger_stop(f"control {answer.reason}", level=logging.INFO)
                desk.tell_displaced(answer.displaced, f"control of {self.robot} {answer.reason}")
            desk.publish_control()
        if answer.outcome is Outcome.TAKEN and answer.displaced is not None:
            desk.cancel_goals(answer.displaced, f"control of {self.robot} {answer.reason}")

    def refuse(self, request: Request[ControlBody], refusal: Refusal) -> None:
        if request.body is None:  # a malformed request: its payload names the sender, if anyone
            self.report(request.user, request.topic, refusal.reason, payload=request.payload)
        else:
            self.report(request.user, request.topic, refusal.reason, client_id=request.body.client_id)
