"""The bridge node: ROS topics ↔ MQTT per the robot's rules, with checks on every command."""

from __future__ import annotations

import logging
import time
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ..config import Fleet, Robot, Role, RosQos
from ..protocol import (
    Envelope,
    MessageId,
    ProtocolError,
    SequenceTracker,
    SystemStatus,
    decode,
    encode,
    error_reply,
    loads,
)
from ..topics import Kind, TopicTree
from .convert import ConversionError
from .link import MqttLink
from .presets import CommandRefused
from .rules import Inbound, Outbound, compile_rules
from .safety import UnsafeCommand, make_safe_twist

log = logging.getLogger("roslink_mqtt.bridge")


def ros_qos(q: RosQos, *, latched: bool = False) -> QoSProfile:
    return QoSProfile(
        depth=q.depth,
        reliability=ReliabilityPolicy.BEST_EFFORT if q.reliability == "best_effort" else ReliabilityPolicy.RELIABLE,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched or q.durability == "transient_local"
                    else DurabilityPolicy.VOLATILE))


class _Throttle:
    """max_rate with newest-wins: send at once if allowed, else keep only the latest for the next slot."""

    __slots__ = ("period", "last", "pending")

    def __init__(self, period: float) -> None:
        self.period, self.last, self.pending = period, -1e18, None


class Bridge:
    """Owns one rclpy node (composition, not inheritance: no clashes with rclpy's own attributes)."""

    def __init__(self, fleet: Fleet, robot: Robot, node: Node, *, password: str | None, broker_url: Any,
                 ca_file: str | None = None) -> None:
        self.node = node
        self.fleet, self.robot, self.topics = fleet, robot, TopicTree(fleet.prefix)
        self.session = int(time.time()) & 0xFFFFFFFF  # grows with every start
        self.owner = ""  # user who last commanded the robot
        self.motion_blocked: str | None = None  # why velocity commands are refused (e-stop, disarmed)
        self.sequences = SequenceTracker()
        self._heartbeat_seq = 0
        outbound, self.inbound = compile_rules(robot, self.topics)
        self.velocity_publishers: list[tuple[Inbound, Any]] = []
        self.publishers_by_rule: dict[str, Any] = {}
        for rule in outbound:
            self._subscribe_ros(rule)
        for name, rule in self.inbound.items():
            latched = rule.spec is not None and rule.spec.name == "emergency_stop"
            pub = node.create_publisher(rule.ros_cls, rule.rule.ros_topic, ros_qos(rule.rule.ros_qos, latched=latched))
            self.publishers_by_rule[name] = pub
            if rule.is_velocity:
                self.velocity_publishers.append((rule, pub))
        self.link = MqttLink(
            client_id=f"roslink-bridge-{robot.name}", username=robot.name, password=password, url=broker_url,
            keepalive=robot.bridge.keepalive, will=(self.topics.heartbeat(robot.name),
                                                    self._heartbeat(SystemStatus.OFFLINE)),
            subscriptions=self.mqtt_subscriptions, on_message=self.on_mqtt, on_up=self.publish_heartbeat,
            ca_file=ca_file)
        node.create_timer(robot.bridge.heartbeat_period, self.publish_heartbeat)
        log.info("bridge for %s: %d ROS→MQTT, %d MQTT→ROS rules", robot.name, len(outbound), len(self.inbound))

    # -- lifecycle ---------------------------------------------------------------
    def start(self) -> None:
        self.link.start()

    def stop(self) -> None:
        """Clean shutdown: tell everyone we are offline (the will covers unclean ones)."""
        self.link.stop([(self.topics.heartbeat(self.robot.name), self._heartbeat(SystemStatus.OFFLINE), 1, True)])

    def mqtt_subscriptions(self) -> list[tuple[str, int]]:
        return [(self.topics.all_from_users(self.robot.name), 1)]

    # -- presence ------------------------------------------------------------------
    def _heartbeat(self, status: SystemStatus) -> bytes:
        self._heartbeat_seq = (self._heartbeat_seq + 1) & 0xFFFFFFFF
        payload = {"type": int(self.robot.type), "name": self.robot.name, "system_status": int(status),
                   "owner_id": self.owner, "mode": 0, "session": self.session}
        return encode(Envelope(MessageId.HEARTBEAT, payload, self.robot.system_id, self._heartbeat_seq))

    def publish_heartbeat(self) -> None:
        status = SystemStatus.EMERGENCY if self.motion_blocked else SystemStatus.ACTIVE
        self.link.publish(self.topics.heartbeat(self.robot.name), self._heartbeat(status), qos=1, retain=True)

    # -- ROS → MQTT ------------------------------------------------------------------
    def _subscribe_ros(self, out: Outbound) -> None:
        link, topic, serialize = self.link_publish, out.topic, out.serialize
        qos, retain = out.rule.mqtt_qos, out.rule.retain
        if not out.period:
            def forward(msg: Any) -> None:
                link(topic, serialize(msg), qos, retain)
        else:
            throttle = _Throttle(out.period)

            def forward(msg: Any) -> None:
                now = time.monotonic()
                if now - throttle.last >= throttle.period:
                    throttle.last, throttle.pending = now, None
                    link(topic, serialize(msg), qos, retain)
                else:
                    throttle.pending = msg

            def flush() -> None:
                if throttle.pending is not None and time.monotonic() - throttle.last >= throttle.period:
                    msg, throttle.pending, throttle.last = throttle.pending, None, time.monotonic()
                    link(topic, serialize(msg), qos, retain)

            self.node.create_timer(out.period / 2, flush)
        self.node.create_subscription(out.ros_cls, out.rule.ros_topic, forward, ros_qos(out.rule.ros_qos))

    def link_publish(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        self.link.publish(topic, payload, qos, retain)

    # -- MQTT → ROS (paho network thread) ---------------------------------------------
    def on_mqtt(self, topic: str, payload: bytes) -> None:
        parsed = self.topics.parse(topic)
        if parsed is None or parsed.kind is not Kind.FROM or parsed.robot != self.robot.name:
            return
        user, name = parsed.user, parsed.name
        rule = self.inbound.get(name)
        if rule is None:
            self.refuse(user, topic, f"no mapping for '{name}' on robot {self.robot.name} "
                                     f"(commands: {', '.join(sorted(self.inbound)) or 'none'})")
            return
        role = self.fleet.roles_of(user).get(self.robot.name)
        if role is not Role.OPERATOR:
            self.refuse(user, topic, f"user '{user}' is not an operator of {self.robot.name}")
            return
        self.handle_command(user, topic, rule, payload)

    def handle_command(self, user: str, topic: str, rule: Inbound, payload: bytes) -> None:
        message_id = sequence = None
        try:
            if rule.spec is not None:
                envelope = decode(payload, rule.spec.message_id)
                message_id, sequence = envelope.message_id, envelope.sequence_number
                if sequence is not None:
                    verdict = self.sequences.check((user, rule.rule.mqtt_topic), sequence)
                    if not verdict.accepted:
                        self.refuse(user, topic, f"{verdict.value} sequence_number {sequence} dropped",
                                    message_id, sequence)
                        return
                msg = rule.build(envelope.payload)
            else:
                msg = rule.build(loads(payload))
            if rule.is_velocity:
                if self.motion_blocked:
                    self.refuse(user, topic, f"{self.motion_blocked}: send cmd/arm to resume", message_id,
                                sequence)
                    return
                make_safe_twist(msg, rule.limits)
        except (ProtocolError, ConversionError, CommandRefused, UnsafeCommand) as err:
            self.refuse(user, topic, str(err), message_id, sequence)
            return
        preset = rule.spec.name if rule.spec is not None else None
        if preset == "emergency_stop":
            self.block_motion(f"emergency stop by {user}")
        elif preset == "disarm":
            self.block_motion(f"disarmed by {user}")
        elif preset == "arm":
            self.motion_blocked = None
        self.owner = user
        self.publishers_by_rule[rule.rule.mqtt_topic].publish(msg)

    def block_motion(self, reason: str) -> None:
        """Zero every velocity output and refuse motion until an operator arms again."""
        self.motion_blocked = reason
        self.stop_motion(reason)

    def stop_motion(self, reason: str) -> None:
        for rule, pub in self.velocity_publishers:
            pub.publish(rule.ros_cls())
        log.warning("stopped %s: %s", self.robot.name, reason)

    def refuse(self, user: str, topic: str, reason: str, message_id: int | None = None,
               sequence: int | None = None) -> None:
        log.debug("refused %s: %s", topic, reason)
        self.link.publish(self.topics.error(self.robot.name, user),
                          error_reply(topic, reason, message_id=message_id, sequence_number=sequence), qos=1)
