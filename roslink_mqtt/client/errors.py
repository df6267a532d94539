"""What can go wrong for an SDK user, as exceptions and as the robot's error reports.

The robot answers every refused input on ``<prefix>/<robot>/to/<user>/error``
(docs/protocol.md, *Errors*); :class:`RobotError` is that object, typed. Service
failures are exceptions because a caller that waits for a value needs to know
why it got none.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


class RoslinkError(Exception):
    """Base of every exception the SDK raises on purpose."""


class ConnectError(RoslinkError):
    """The broker could not be reached or refused the login."""


class ServiceError(RoslinkError):
    """A service call failed; ``reason`` is the robot's (or the provider's) explanation."""

    def __init__(self, robot: str, service: str, reason: str) -> None:
        super().__init__(f"{robot}/{service}: {reason}")
        self.robot, self.service, self.reason = robot, service, reason


class ServiceTimeout(ServiceError, TimeoutError):
    """No reply within the caller's timeout (robot offline, broker dropped the call, …)."""


@dataclass(frozen=True, slots=True)
class RobotError:
    """One message from ``to/<user>/error``: the robot refused something we sent."""

    robot: str
    topic: str  # what we published to
    error: str  # why it was refused (field path included)
    message_id: int | None = None
    sequence_number: int | None = None

    @classmethod
    def from_json(cls, robot: str, body: Any) -> RobotError:
        if not isinstance(body, dict):
            return cls(robot, "", f"malformed error report: {body!r}")
        mid, seq = body.get("message_id"), body.get("sequence_number")
        return cls(robot, str(body.get("topic", "")), str(body.get("error", "")),
                   mid if isinstance(mid, int) else None, seq if isinstance(seq, int) else None)


class CommandRefused(RoslinkError):
    """A command was refused by the robot (raised by commands sent with ``check=``)."""

    def __init__(self, error: RobotError) -> None:
        super().__init__(f"{error.robot} refused {error.topic}: {error.error}")
        self.error = error
