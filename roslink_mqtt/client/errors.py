"""What can go wrong for an SDK user, as exceptions and as the robot's error reports.

The robot answers every refused input on ``<prefix>/<robot>/to/<user>/error``
(docs/protocol.md, *Errors*); :class:`RobotError` is that object, typed. Service
failures are exceptions because a caller that waits for a value needs to know
why it got none.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..protocol import ProtocolError
from ..protocol.control import ErrorReport, Notice
from ..protocol.errors import RoslinkError as RoslinkError  # the SDK names it here too


class InvalidArgument(RoslinkError, ValueError):
    """An argument the SDK cannot use (a malformed type name, a timeout out of range, no robot named …).

    Raised before anything is sent: the call is a programming or configuration error, not a network one.
    """


class InvalidType(RoslinkError, TypeError):
    """A value of the wrong Python type (service arguments or a publish() that are not a dict …)."""


class WaitTimeout(RoslinkError, TimeoutError):
    """Nothing came within the caller's timeout (a state message, a robot coming online)."""


class NotGranted(RoslinkError, PermissionError):
    """The broker does not let this login use the robot: no grant, or one the fleet removed (the message says)."""


class NodeDestroyed(RoslinkError, RuntimeError):
    """An entity was created on a node after ``destroy_node()``; its connection is closed."""


class SubscriptionFailed(RoslinkError, ConnectionError):
    """A subscription ended without a recorded cause; nothing more will arrive on it."""


class ConnectError(RoslinkError):
    """The broker could not be reached or refused the login."""


class LoginRefused(ConnectError):
    """The broker refused the login itself (CONNACK 1, 2, 4 or 5: bad credentials, not authorised, …).

    Retrying cannot fix that, and every failed attempt counts against the broker's
    login throttle for this address, slowing down the user's other programs. So the
    client stops reconnecting, and every later command, call or subscription raises this.
    """


class NotConnectedError(ConnectError):
    """A command, call or subscription on a client that is not connected; nothing was sent.

    Raised at once instead of queueing: a client never connected (no ``with`` and no
    ``connect()``), closed, or between a lost connection and the next reconnect. A
    command queued until a reconnect would reach the robot late or never; the caller
    must know.
    """


class CommandNotConfirmed(RoslinkError, TimeoutError):
    """The broker did not acknowledge a command (QoS 1 PUBACK) in time: it may not have reached the robot.

    Emergency stops wait for that acknowledgement, so a stop is never lost without
    the caller hearing of it.
    """


class ServiceError(RoslinkError):
    """A service call failed; ``reason`` is the robot's (or the provider's) explanation."""

    def __init__(self, robot: str, service: str, reason: str) -> None:
        super().__init__(f"{robot}/{service}: {reason}")
        self.robot, self.service, self.reason = robot, service, reason


class ServiceTimeout(ServiceError, TimeoutError):
    """No reply within the caller's timeout (robot offline, broker dropped the call, …)."""


@dataclass(frozen=True, slots=True)
class RobotError:
    """One message from ``to/<user>/error``: the robot refused something we sent.

    ``client_id`` is the sender the report names: a client shows only reports with
    its own id or with none (a sender that did not say could be any program). A
    report the client itself makes up — the broker refused our login, so nothing
    will reach any robot — has ``robot`` and ``topic`` empty.
    """

    robot: str
    topic: str  # what we published to
    error: str  # why it was refused (field path included)
    message_id: int | None = None
    sequence_number: int | None = None
    client_id: str | None = None
    request_id: str | int | None = None  # the refused request's id (a goal, a cancel), when it had one

    @classmethod
    def from_json(cls, robot: str, body: Any) -> RobotError:
        """A report from ``robot``'s error topic (its payload, or the body decoded); a malformed one is still shown,
        as what it is."""
        try:
            report = ErrorReport.from_body(body)
        except ProtocolError as err:
            return cls(robot, "", f"malformed error report: {err}")
        return cls(robot, report.topic, report.error, report.message_id, report.sequence_number, report.client_id,
                   report.id)


@dataclass(frozen=True, slots=True)
class RobotNotice:
    """One message from ``to/<user>/notice``: the robot carried out something we sent, but not as sent.

    Today that is a twist clamped to the robot's velocity limits, said once per stream (its first clamped twist).
    Not an error: nothing was refused, and ``check=`` does not raise for it.
    """

    robot: str
    topic: str  # what we published to
    notice: str  # what the robot changed, and why
    message_id: int | None = None
    sequence_number: int | None = None
    client_id: str | None = None

    @classmethod
    def from_json(cls, robot: str, payload: bytes) -> RobotNotice:
        """A notice from ``robot``; a malformed one is still shown, as what it is."""
        try:
            body = Notice.from_json(payload)
        except ProtocolError as err:
            return cls(robot, "", f"malformed notice: {err}")
        return cls(robot, body.topic, body.notice, body.message_id, body.sequence_number, body.client_id)


class GoalError(RoslinkError):
    """A goal was refused (on the robot's error topic), rejected by its action server, or never answered."""

    def __init__(self, robot: str, action: str, goal_id: str, reason: str) -> None:
        super().__init__(f"{robot}/{action} goal '{goal_id}': {reason}")
        self.robot, self.action, self.goal_id, self.reason = robot, action, goal_id, reason


class ParameterError(RoslinkError):
    """A parameter request was refused, or the node did not answer (not running, timeout)."""

    def __init__(self, robot: str, node: str, reason: str) -> None:
        super().__init__(f"{robot}/{node} parameters: {reason}")
        self.robot, self.node, self.reason = robot, node, reason


class CommandRefused(RoslinkError):
    """A command was refused by the robot (raised by commands sent with ``check=``)."""

    def __init__(self, error: RobotError) -> None:
        super().__init__(f"{error.robot} refused {error.topic}: {error.error}")
        self.error = error


class SnapshotError(RoslinkError):
    """A snapshot was refused by the robot, or did not arrive whole (see ``reason``)."""

    def __init__(self, robot: str, snapshot_id: str, reason: str) -> None:
        # refused before the robot gave it an id (a viewer asking, no snapshot section): no id to show
        super().__init__(f"{robot} snapshot '{snapshot_id}': {reason}" if snapshot_id else
                         f"{robot}: snapshot refused: {reason}")
        self.robot, self.snapshot_id, self.reason = robot, snapshot_id, reason
