"""Log lines of SDK nodes into the robot's ``/rosout`` (docs/protocol.md, "Logging").

``from/<user>/log/<node>`` becomes an ``rcl_interfaces/msg/Log`` named after the SDK node, so a program
without ROS shows up in ``ros2 topic echo /rosout``, rqt_console and bags like any ROS node. Operators only
(a viewer's programs do not write the robot's log); each user gets at most RATE lines per second (a burst
of BURST), beyond which lines are dropped and the user is told once per episode on its error topic.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from rcl_interfaces.msg import Log
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ..config import Role
from ..protocol import ProtocolError
from ..protocol.rosout import LogLine
from ..topics import Verb
from .authorize import refusal

RATE, BURST = 100.0, 200  # log lines per second per user, and how many may come at once
# rclpy's own /rosout publisher profile: late joiners (rqt_console) get the recent lines
ROSOUT_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class RosoutForwarder:
    def __init__(self, node: Node, robot: str, role_of: Callable[[str], Role | None],
                 refuse: Callable[..., None]) -> None:
        self.node, self.robot, self.role_of, self.refuse = node, robot, role_of, refuse
        self.publisher = node.create_publisher(Log, "/rosout", ROSOUT_QOS)
        self._buckets: dict[str, tuple[float, float, bool]] = {}  # user -> (tokens, at, told)

    def handle(self, user: str, name: str, topic: str, payload: bytes) -> None:
        """One log line (MQTT thread); publishing on an rclpy publisher is thread-safe."""
        why = refusal(user, self.role_of(user), Verb.LOG, name, robot=self.robot)
        if why:
            self.refuse(user, topic, why, payload=payload)
            return
        if not self._take(user, topic):
            return
        try:
            line = LogLine.from_json(payload)
        except ProtocolError as err:
            self.refuse(user, topic, str(err), payload=payload)
            return
        now = self.node.get_clock().now().to_msg()
        self.publisher.publish(Log(stamp=now, level=line.level, name=name, msg=line.msg, file=line.file,
                                   function=line.function, line=line.line))

    def _take(self, user: str, topic: str) -> bool:
        now = time.monotonic()
        tokens, at, told = self._buckets.get(user, (float(BURST), now, False))
        tokens = min(float(BURST), tokens + (now - at) * RATE)
        if tokens >= 1.0:
            self._buckets[user] = (tokens - 1.0, now, False)
            return True
        self._buckets[user] = (tokens, now, True)
        if not told:
            self.refuse(user, topic, f"log lines from {user} dropped: more than {RATE:g} per second "
                                  f"(bursts of {BURST}) to {self.robot}'s /rosout")
        return False
