"""A ROS 2 bag (``ros2 bag record -s mcap``, or a snapshot) played as a robot's MQTT state, through its rules.

``roslink-mqtt play bag.mcap --rules robots.yaml --robot turtle1`` turns each bag message that one of the robot's
``ros_to_mqtt`` rules maps into what that robot's bridge would have published: the same conversion (presets such
as ``global_motion``, generic JSON, CBOR, raw images), the same ``max_rate`` (newest wins, on the bag's clock), the
same retained flags, plus a heartbeat a second and the robot's description, so dashboards, scripts and tests see
that robot as it was with no robot there. The CDR is decoded with the installed ROS message types (rclpy's
deserializer), the very classes the bridge converts: this needs the bridge's ROS packages, not a robot.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ... import ros_names
from ...config import Robot
from ...config.model import Direction
from ...protocol import Envelope, MessageId, SystemStatus, encode
from ...topics import TopicTree
from ..core.throttle import Throttle
from .description import description_message
from .rules import Outbound, RuleError, compile_outbound

HEARTBEAT_PERIOD = 1.0  # s of the bag's time


class _Route:
    def __init__(self, out: Outbound) -> None:
        self.out = out
        self.throttle = Throttle(out.rule.max_rate) if out.rule.max_rate else None


def bag_frames(path: str | Path, robot: Robot, topics: TopicTree) -> Iterator[Any]:
    """The bag's messages as ``robot``'s MQTT state (client/player.py's :class:`Frame`), in log-time order."""
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    from ...client.player import Frame

    routes: dict[str, _Route] = {}
    for rule in robot.rules:
        if rule.direction is Direction.ROS_TO_MQTT:
            routes[ros_names.relative(rule.ros_topic)] = _Route(compile_outbound(rule, robot, topics))
    if not routes:
        raise RuleError(f"{robot.name} has no ros_to_mqtt rules: nothing of a bag would reach MQTT")
    heartbeat_topic = topics.heartbeat(robot.name)
    session = int(time.time()) & 0xFFFFFFFF
    beats = 0

    def heartbeat(at: float) -> Frame:
        nonlocal beats
        beats += 1
        payload = {"type": int(robot.type), "name": robot.name, "system_status": int(SystemStatus.ACTIVE),
                   "owner_id": "", "mode": 0, "session": session}
        return Frame(at, heartbeat_topic, encode(Envelope(MessageId.HEARTBEAT, payload, robot.system_id, beats)),
                     True)

    description_topic, description = description_message(robot, topics)
    yield Frame(0.0, description_topic, description, True)
    first: int | None = None
    next_beat = 0.0
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            route = routes.get(ros_names.relative(channel.topic))
            if route is None or channel.message_encoding != "cdr":
                continue
            first = message.log_time if first is None else first
            at = (message.log_time - first) / 1e9
            while next_beat <= at:
                yield heartbeat(next_beat)
                next_beat += HEARTBEAT_PERIOD
            for other in routes.values():  # a kept message goes out once its slot opens (newest wins)
                if other.throttle is not None and (kept := other.throttle.flush(at)) is not None:
                    yield Frame(at, other.out.topic, other.out.serialize(kept), other.out.rule.retain)
            msg = deserialize_message(message.data, route.out.ros_cls)
            if route.throttle is not None and route.throttle.offer(msg, at) is None:
                continue
            yield Frame(at, route.out.topic, route.out.serialize(msg), route.out.rule.retain)
    if first is None:
        raise RuleError(f"no message of {path} is on a ROS topic {robot.name}'s rules map (they map "
                        f"{', '.join(sorted(routes))}); is it a ROS 2 bag (cdr messages)?")
