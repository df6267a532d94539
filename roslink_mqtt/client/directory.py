"""Which robots exist and whether they are online, from their retained heartbeats.

A robot's bridge keeps a retained heartbeat on ``<prefix>/<robot>/heartbeat``
and leaves an *offline* one as its last-will, so a client learns every robot's
state the moment it subscribes. A retained heartbeat can also be old news
(the bridge froze, or the broker restarted with a stale retained message), so
a robot also counts as offline when no heartbeat arrived for ``stale_after``
seconds. Pure logic: the client feeds it messages, tests feed it bytes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum

from ..protocol import FlightMode, MessageId, ProtocolError, RobotType, SystemStatus, decode

DEFAULT_STALE_AFTER = 5.0  # s; the bridge beats once a second


@dataclass(frozen=True, slots=True)
class RobotInfo:
    """What the latest heartbeat of one robot says."""

    name: str
    system_id: int
    type: RobotType | int
    system_status: SystemStatus | int
    mode: FlightMode | int
    owner: str  # user who holds control of it (the control lease), '' when none
    session: int  # grows with every bridge start: a new value means the bridge restarted
    received_at: float  # time.monotonic() of the heartbeat
    stale_after: float = DEFAULT_STALE_AFTER
    host: str = ""  # where its bridge runs ('' from bridges older than one-bridge claims)
    pid: int = 0
    bridge_since: float = 0.0  # when its bridge started, s since the epoch

    @property
    def online(self) -> bool:
        """Its bridge is connected: the heartbeat is not the offline last-will and is recent."""
        return self.system_status != SystemStatus.OFFLINE and time.monotonic() - self.received_at <= self.stale_after

    @property
    def blocked(self) -> bool:
        """Motion is blocked (emergency stop or disarm) until an operator arms it."""
        return self.system_status == SystemStatus.EMERGENCY


def _enum(cls: type[IntEnum], value: int) -> int:
    try:
        return cls(value)
    except ValueError:
        return value


class RobotDirectory:
    """Latest heartbeat per robot, thread-safe; ``changed`` wakes waiters on every update."""

    def __init__(self, stale_after: float = DEFAULT_STALE_AFTER) -> None:
        self.stale_after = stale_after
        self._robots: dict[str, RobotInfo] = {}
        self.changed = threading.Condition()

    def update(self, robot: str, payload: bytes) -> RobotInfo | None:
        """Record a heartbeat message from ``<prefix>/<robot>/heartbeat``; None if it is not one.

        An empty payload (a cleared retained message) forgets the robot.
        """
        if not payload:
            with self.changed:
                self._robots.pop(robot, None)
                self.changed.notify_all()
            return None
        try:
            envelope = decode(payload, MessageId.HEARTBEAT)
        except ProtocolError:
            return None
        p = envelope.payload
        info = RobotInfo(robot, envelope.system_id, _enum(RobotType, p["type"]),
                         _enum(SystemStatus, p["system_status"]), _enum(FlightMode, p["mode"]), p["owner_id"],
                         p["session"], time.monotonic(), self.stale_after, p["host"], p["pid"], p["since"])
        with self.changed:
            self._robots[robot] = info
            self.changed.notify_all()
        return info

    def touch(self) -> None:
        """Wake the waiters: something a predicate reads besides the heartbeats changed."""
        with self.changed:
            self.changed.notify_all()

    def get(self, robot: str) -> RobotInfo | None:
        with self.changed:
            return self._robots.get(robot)

    def snapshot(self) -> dict[str, RobotInfo]:
        with self.changed:
            return dict(sorted(self._robots.items()))

    def wait(self, predicate: Callable[[dict[str, RobotInfo]], bool], timeout: float) -> bool:
        """Block until ``predicate(robots)`` holds; False on timeout."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while not predicate(self._robots):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                # Wake at least once a second: "online" also changes by time passing (staleness).
                self.changed.wait(min(left, 1.0))
            return True
