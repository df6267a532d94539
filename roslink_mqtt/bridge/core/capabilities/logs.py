"""``log/<node>``: log lines of SDK nodes into the robot's ``/rosout`` (docs/protocol.md, "Logging"). ROS-free.

Operators only (a viewer's programs do not write the robot's log); each user gets at most RATE lines per
second (a burst of BURST), beyond which lines are dropped and the user is told once per episode on its error
topic. The port (:class:`RosoutPort`, :mod:`roslink_mqtt.bridge.ros.rosout` with rclpy) publishes the line as an
``rcl_interfaces/msg/Log`` named after the SDK node, so a program without ROS shows up in
``ros2 topic echo /rosout``, rqt_console and bags like any ROS node.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Protocol

from ....authorize import refusal
from ....protocol.rosout import LogLine
from ....topics import Verb
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring

RATE, BURST = 100.0, 200  # log lines per second per user, and how many may come at once


class RosoutPort(Protocol):
    def publish_log(self, node_name: str, line: LogLine) -> None:
        """Publish ``line`` on ``/rosout`` as node ``node_name`` (any thread)."""
        ...


ROSOUT_PORT = PortKey[RosoutPort]("rosout", "log lines onto /rosout")


class LogLines:
    """Log lines from MQTT users' programs, rate-limited per user."""

    @classmethod
    def build(cls, wiring: Wiring) -> LogLines:
        """From the bridge's wiring (capabilities/registry.py)."""
        return cls(wiring.robot.name, wiring.ports.get(ROSOUT_PORT), wiring.report)

    verb = Verb.LOG

    def __init__(self, robot: str, port: RosoutPort, report: Report) -> None:
        self.robot, self.port, self.report = robot, port, report
        self._buckets: dict[str, tuple[float, float, bool]] = {}  # user -> (tokens, at, told)
        self._lock = threading.Lock()  # the operators' and the viewers' links deliver on two threads

    def parse(self, name: str, payload: bytes) -> LogLine:
        return LogLine.from_json(payload)

    def gate(self, request: Request[LogLine], gates: Gates) -> Refusal | None:
        why = refusal(request.user, request.role, Verb.LOG, request.name, robot=self.robot)
        return Refusal(why) if why else None

    def run(self, request: Request[LogLine]) -> None:
        assert request.body is not None
        if self._take(request):
            self.port.publish_log(request.name, request.body)

    def _take(self, request: Request[LogLine]) -> bool:
        """One token of the user's bucket; the first line dropped in an episode says so."""
        user, now = request.user, time.monotonic()
        with self._lock:
            tokens, at, told = self._buckets.get(user, (float(BURST), now, False))
            tokens = min(float(BURST), tokens + (now - at) * RATE)
            if tokens >= 1.0:
                self._buckets[user] = (tokens - 1.0, now, False)
                return True
            self._buckets[user] = (tokens, now, True)
        if not told:
            self.report(user, request.topic, f"log lines from {user} dropped: more than {RATE:g} per second "
                                             f"(bursts of {BURST}) to {self.robot}'s /rosout")
        return False

    def refuse(self, request: Request[LogLine], refusal: Refusal) -> None:
        body = request.body
        self.report(request.user, request.topic, refusal.reason,
                    client_id=body.client_id if body is not None else refusal.client_id)


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (LogLines,)
