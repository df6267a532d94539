"""The bridge: ROS topics ↔ MQTT per the robot's rules, with presence, checks and failsafe stops."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import replace
from typing import Any

from rclpy.node import Node

from ..config import Fleet, Robot, Role
from ..presence import MAX_PRESENCE_BYTES, OperatorTracker, Presence, classify_presence
from ..protocol import (
    AckResult,
    Envelope,
    MessageId,
    ProtocolError,
    SequenceTracker,
    SystemStatus,
    decode,
    encode,
    error_reply,
    loads,
    sender_id,
)
from ..protocol.control import pop_generic_sender
from ..topics import Kind, TopicTree, Verb
from .access import access_reports, cleared_reports
from .authorize import refusal
from .convert import ConversionError, converter_for
from .failsafe import Failsafe, late_motion
from .link import MqttLink, bridge_client_id
from .on_demand import OnDemandPublishers
from .presets import CommandRefused
from .ros_types import UnknownTypeError, load_interface
from .rules import Inbound, Outbound, RuleError, compile_rules, ros_qos
from .safety import STANDSTILL, VELOCITY_TYPES, UnsafeCommand, is_standstill, make_safe_twist
from .services import ProvidedServices, ServiceCaller
from .systemd import SystemdNotifier
from .throttle import Throttle

log = logging.getLogger("roslink_mqtt.bridge")

SUPERVISION_RATE = 20.0  # Hz: failsafe checks, stop repeats, link check
GOAL_PRESETS = ("go_to_waypoint", "takeoff")
COMMAND_SERVICE_TIMEOUT = 5.0  # s for preset commands carried out by a ROS service
MAX_OVERSIZED_LOGGED = 256  # presence clients whose oversized payloads are logged (once each)


def _static_part(robot: Robot) -> tuple:
    """What a reload cannot change in a running bridge (rules and settings), ignoring line numbers."""
    return (robot.system_id, robot.type, robot.bridge, tuple(replace(r, line=None) for r in robot.rules),
            tuple(replace(s, line=None) for s in robot.services))


class Bridge:
    """Owns one rclpy node (composition, not inheritance: no clashes with rclpy's own attributes).

    Threads: ROS callbacks and the supervision timer run in the executor;
    MQTT messages arrive on paho's network thread. ``_lock`` serialises
    everything that touches motion state, so a stop and a command can never
    interleave.
    """

    def __init__(self, fleet: Fleet, robot: Robot, node: Node, *, password: str | None, broker_url: Any,
                 ca_file: str | None = None) -> None:
        self.node = node
        self.fleet, self.robot, self.topics = fleet, robot, TopicTree(fleet.prefix)
        settings = robot.bridge
        self.session = int(time.time()) & 0xFFFFFFFF  # grows with every start
        self.owner = ""  # user who last commanded the robot
        self.motion_blocked: str | None = None  # why velocity commands are refused (e-stop, disarmed)
        self.sequences = SequenceTracker()
        self.operators = OperatorTracker(settings.operator_timeout)
        self.failsafe = Failsafe(settings.command_timeout)
        self._lock = threading.RLock()
        self._heartbeat_seq = self._ack_seq = 0
        self._pending_heartbeat: tuple[float, Any] | None = None  # (sent at, paho info) awaiting PUBACK
        self._stop_repeats_left = 0
        self._oversized_presence: set[tuple[str, str]] = set()  # clients already told (paho thread only)
        self._grants: tuple[Fleet, dict[str, Role | None]] = (fleet, {})  # swapped whole on reload
        outbound, self.inbound = compile_rules(robot, self.topics)
        self.velocity_publishers: list[tuple[Inbound, Any]] = []
        self.publishers_by_rule: dict[str, Any] = {}
        for rule in outbound:
            self._subscribe_ros(rule)
        self.command_services: dict[str, Any] = {}  # preset commands carried out by calling a ROS service
        self._service_commands: dict[Any, tuple[float, str, int | None, int | None, str]] = {}
        for name, rule in self.inbound.items():
            if rule.is_service:
                self.command_services[name] = node.create_client(rule.ros_cls, rule.rule.ros_topic)
                continue
            if rule.rule.on_demand:
                continue  # its ROS publisher comes and goes with its advertisers (OnDemandPublishers)
            latched = rule.spec is not None and rule.spec.name == "emergency_stop"
            pub = node.create_publisher(rule.ros_cls, rule.rule.ros_topic, ros_qos(rule.rule.ros_qos, latched=latched))
            self.publishers_by_rule[name] = pub
            if rule.is_velocity:
                self.velocity_publishers.append((rule, pub))
        self.failsafe_actions = []
        for i, action in enumerate(settings.on_failsafe):
            try:
                cls = load_interface(action.ros_type)
                message = converter_for(cls).from_dict(action.message)
                if action.ros_type in VELOCITY_TYPES and make_safe_twist(message, STANDSTILL):
                    raise UnsafeCommand("a failsafe action must not move the robot: every velocity must be 0")
            except (UnknownTypeError, ConversionError, UnsafeCommand) as err:
                raise RuleError(f"bridge.on_failsafe[{i}]: {err}") from None
            self.failsafe_actions.append((node.create_publisher(cls, action.ros_topic, 10), message))
        role_of = self.role_of
        try:
            self.caller = ServiceCaller(node, robot, self.topics, self._publish_reliable, role_of)
        except UnknownTypeError as err:
            raise RuleError(f"services: {err}") from None
        self.provided = ProvidedServices(node, robot, self.topics, self._publish_reliable, role_of,
                                         self.operators.is_live, self.refuse,
                                         max_concurrent=settings.provided_max_calls,
                                         queue_depth=settings.provided_queue_depth)
        self.on_demand = OnDemandPublishers(node, {n: r for n, r in self.inbound.items() if r.rule.on_demand},
                                            {n for n, r in self.inbound.items() if not r.rule.on_demand},
                                            role_of, self.operators.is_live, self.refuse, robot=robot.name)
        self.link = MqttLink(
            client_id=bridge_client_id(robot.name), username=robot.name, password=password, url=broker_url,
            keepalive=settings.keepalive, will=(self.topics.heartbeat(robot.name),
                                                self._heartbeat(SystemStatus.OFFLINE)),
            subscriptions=self.mqtt_subscriptions, on_message=self.on_mqtt, on_up=self.on_link_up,
            on_down=self.on_link_down, ca_file=ca_file)
        self.systemd = SystemdNotifier()
        node.create_timer(settings.heartbeat_period, self.publish_heartbeat)
        node.create_timer(1.0 / SUPERVISION_RATE, self.supervise)
        log.info("bridge for %s: %d ROS→MQTT, %d MQTT→ROS rules, %d velocity outputs", robot.name, len(outbound),
                 len(self.inbound), len(self.velocity_publishers))

    def role_of(self, user: str) -> Role | None:
        """The user's role on this robot, computed once per user and fleet version (any thread)."""
        fleet, cache = self._grants  # one read: a reload swaps both at once
        try:
            return cache[user]
        except KeyError:
            role = cache[user] = fleet.roles_of(user).get(self.robot.name)
            return role

    def reload(self, fleet: Fleet) -> None:
        """Apply a re-read fleet file's users and grants now (SIGHUP); rule changes need a restart.

        The broker applies the same file on its own SIGHUP; the bridge must follow, or a newly granted
        operator stays refused and a revoked one keeps control until the dead-man stops the robot.
        Revoking an operator who owns the current motion stops the robot at once.
        """
        robot = fleet.robots.get(self.robot.name)
        if robot is None:
            log.error("reload: robot %s is no longer in %s; keeping the current grants", self.robot.name, fleet.file)
            return
        if _static_part(robot) != _static_part(self.robot):
            log.warning("reload: the rules or bridge settings of %s changed; restart the bridge to apply them "
                        "(users and grants apply now)", self.robot.name)
        before, after = self.fleet.users_of(self.robot.name), fleet.users_of(self.robot.name)
        with self._lock:
            old_fleet, self.fleet, self._grants = self.fleet, fleet, (fleet, {})
        self.publish_access(cleared=cleared_reports(old_fleet, fleet, self.robot.name, self.topics))
        for user in sorted(set(before) - set(after)):
            self.link.unsubscribe(self.topics.operators_of(user))
        for user in sorted(set(after) - set(before)):
            self.link.subscribe(self.topics.operators_of(user), 1)
        demoted = sorted(u for u, role in before.items() if role is Role.OPERATOR and after.get(u) is not Role.OPERATOR)
        for user in demoted:
            self.provided.withdraw_user(user, f"{user} is no longer an operator of {self.robot.name}")
            self.on_demand.withdraw_user(user)
            with self._lock:
                why = self.failsafe.operator_gone(user)
                if why:
                    self.trigger_stop(f"{why} (operator grant removed)")
        log.info("reloaded %s: %d users may see %s (%s)", fleet.file, len(after), self.robot.name,
                 ", ".join(f"{u}:{r.value}" for u, r in sorted(after.items())) or "none")

    def _publish_reliable(self, topic: str, payload: bytes) -> None:
        self.link.publish(topic, payload, qos=1)

    # -- lifecycle ---------------------------------------------------------------
    def start(self) -> None:
        self.link.start()
        self.systemd.ready(f"connecting to {self.link.url}")

    def stop(self) -> None:
        """Clean shutdown: stop the robot, tell everyone we are offline (the will covers unclean ones)."""
        self.systemd.stopping()
        with self._lock:
            self._publish_zero_velocity()
        self.link.stop([(self.topics.heartbeat(self.robot.name), self._heartbeat(SystemStatus.OFFLINE), 1, True)])

    def mqtt_subscriptions(self) -> list[tuple[str, int]]:
        subs = [(self.topics.all_from_users(self.robot.name), 1)]
        subs += [(self.topics.operators_of(user), 1) for user in sorted(self.fleet.users_of(self.robot.name))]
        return subs

    def on_link_up(self) -> None:
        self.systemd.status(f"connected to {self.link.url}")
        with self._lock:
            self.failsafe.link_up = True
            self._pending_heartbeat = None
        self.publish_heartbeat()
        self.publish_access()

    def publish_access(self, cleared: list[str] = ()) -> None:
        """Retained ``to/<user>/access`` for every granted user (bridge/access.py says why); clear ``cleared``."""
        for topic in cleared:
            self.link.publish(topic, b"", qos=1, retain=True)
        for topic, body in access_reports(self.fleet, self.robot.name, self.topics).items():
            self.link.publish(topic, body, qos=1, retain=True)

    def on_link_down(self, reason: str) -> None:
        closing = self.link.closing  # our own stop() disconnected: a shutdown, not a failure
        self.systemd.status("disconnected (stopping)" if closing else f"broker lost ({reason}); reconnecting")
        with self._lock:
            why = self.failsafe.link_lost()
            if why:
                if closing:
                    self.trigger_stop("the bridge is shutting down", level=logging.INFO)
                else:
                    self.trigger_stop(f"{why} ({reason})")

    # -- presence ------------------------------------------------------------------
    def _heartbeat(self, status: SystemStatus) -> bytes:
        self._heartbeat_seq = (self._heartbeat_seq + 1) & 0xFFFFFFFF
        payload = {"type": int(self.robot.type), "name": self.robot.name, "system_status": int(status),
                   "owner_id": self.owner, "mode": 0, "session": self.session}
        return encode(Envelope(MessageId.HEARTBEAT, payload, self.robot.system_id, self._heartbeat_seq))

    def publish_heartbeat(self) -> None:
        status = SystemStatus.EMERGENCY if self.motion_blocked else SystemStatus.ACTIVE
        info = self.link.publish(self.topics.heartbeat(self.robot.name), self._heartbeat(status), qos=1, retain=True)
        with self._lock:
            if info is not None and self._pending_heartbeat is None:
                self._pending_heartbeat = (time.monotonic(), info)

    # -- supervision (executor, 20 Hz) -------------------------------------------------
    def supervise(self) -> None:
        now = time.monotonic()
        self.systemd.ping()  # from here: a starved executor stops the pings and systemd restarts us
        with self._lock:
            self._check_link(now)
            for user in self.operators.expire(now):
                why = self.failsafe.operator_gone(user)
                if why:
                    self.trigger_stop(f"{why} (no heartbeat for {self.operators.timeout:g} s)")
            why = self.failsafe.tick(now, self.operators.live_users())
            if why:
                self.trigger_stop(why)
            if self._stop_repeats_left > 0:
                self._stop_repeats_left -= 1
                self._publish_zero_velocity()
        self.caller.expire(now)
        self.provided.expire(now)
        self._expire_command_services(now)
        self.provided.refresh()
        self.on_demand.refresh()

    def _check_link(self, now: float) -> None:
        """A heartbeat not acknowledged within link_timeout means the broker stopped answering."""
        pending = self._pending_heartbeat
        if pending is None:
            return
        sent_at, info = pending
        if info.is_published():
            self._pending_heartbeat = None
            if not self.failsafe.link_up and self.link.connected.is_set():
                self.failsafe.link_up = True
                log.info("broker answers again")
        elif now - sent_at > self.robot.bridge.link_timeout and self.failsafe.link_up:
            why = self.failsafe.link_lost()
            log.warning("broker silent for %.2f s", now - sent_at)
            if why:
                self.trigger_stop(f"{why} (no answer for {self.robot.bridge.link_timeout:g} s)")

    def trigger_stop(self, reason: str, level: int = logging.WARNING) -> None:
        """Failsafe stop: zero velocity now and a few more times, run on_failsafe actions, tell users why.

        ``level`` INFO is for stops that are the expected end of something (a client that signed off, a
        requested shutdown): the robot stops exactly the same way, but the log does not cry failure.
        """
        with self._lock:
            self.failsafe.stopped()
            self._publish_zero_velocity()
            self._stop_repeats_left = round(self.robot.bridge.stop_hold * SUPERVISION_RATE)
            for pub, msg in self.failsafe_actions:
                pub.publish(msg)
        log.log(level, "%s of %s: %s", "failsafe stop" if level >= logging.WARNING else "stop", self.robot.name,
                reason)
        self.publish_ack(0, None, AckResult.FAILSAFE, reason)

    def _publish_zero_velocity(self) -> None:
        for rule, pub in self.velocity_publishers:
            pub.publish(rule.ros_cls())

    def publish_ack(self, command: int, sequence: int | None, result: AckResult, text: str) -> None:
        self._ack_seq = (self._ack_seq + 1) & 0xFFFFFFFF
        payload = {"command": int(command), "command_sequence": -1 if sequence is None else sequence,
                   "result": int(result), "text": text}
        self.link.publish(self.topics.state(self.robot.name, "ack"),
                          encode(Envelope(MessageId.ACK, payload, self.robot.system_id, self._ack_seq)), qos=1)

    # -- ROS → MQTT ------------------------------------------------------------------
    def _subscribe_ros(self, out: Outbound) -> None:
        link, topic, serialize = self.link_publish, out.topic, out.serialize
        qos, retain = out.rule.mqtt_qos, out.rule.retain
        if not out.period:
            def forward(msg: Any) -> None:
                link(topic, serialize(msg), qos, retain)
        else:
            throttle = Throttle(1.0 / out.period)

            def forward(msg: Any) -> None:
                if throttle.offer(msg, time.monotonic()) is not None:
                    link(topic, serialize(msg), qos, retain)

            def flush() -> None:
                msg = throttle.flush(time.monotonic())
                if msg is not None:
                    link(topic, serialize(msg), qos, retain)

            self.node.create_timer(out.period / 4, flush)
        self.node.create_subscription(out.ros_cls, out.rule.ros_topic, forward, ros_qos(out.rule.ros_qos))

    def link_publish(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        self.link.publish(topic, payload, qos, retain)

    # -- MQTT → ROS (paho network thread) ---------------------------------------------
    def on_mqtt(self, topic: str, payload: bytes, retained: bool = False, arrived: float | None = None) -> None:
        """One MQTT message; ``arrived`` (monotonic, from the link) lets late motion be dropped, not executed."""
        parsed = self.topics.parse(topic)
        if parsed is None:
            return
        if parsed.kind is Kind.OPERATOR:
            self.on_operator(parsed.user, parsed.client_id, payload)
            return
        if parsed.kind is not Kind.FROM or parsed.robot != self.robot.name:
            return
        user, verb, leaf = parsed.user, parsed.verb, parsed.name
        if retained and not (verb is not None and verb.retained_by_sender):
            # A retained command is replayed by the broker whenever the bridge (re)subscribes: executing it
            # would drive the robot on a stale order. Only offers and advertisements are meant to be retained.
            if payload:
                self.refuse(user, topic, "ignored a retained command from the broker: publish commands "
                                         "without the retain flag (and clear this one with an empty retained message)",
                            payload=payload)
            return
        if verb is Verb.CALL:
            self.caller.handle(user, leaf, payload)
            return
        if verb is Verb.PROVIDE:
            self.provided.offer(user, leaf, topic, payload)
            return
        if verb is Verb.RESPONSE:
            self.provided.response(user, leaf, topic, payload)
            return
        if verb is Verb.ADVERTISE:
            self.on_demand.advertise(user, leaf, topic, payload)
            return
        name = parsed.leaf
        rule = self.inbound.get(name)
        if rule is None:
            self.refuse(user, topic, f"no mapping for '{name}' on robot {self.robot.name} "
                                     f"(commands: {', '.join(sorted(self.inbound)) or 'none'})", payload=payload)
            return
        why = refusal(user, self.role_of(user), Verb.CMD, name, robot=self.robot.name)
        if why:
            self.refuse(user, topic, why, payload=payload)
            return
        self.handle_command(user, topic, rule, payload, arrived)

    def on_operator(self, user: str, client_id: str, payload: bytes) -> None:
        """Operator presence. Classified before the lock (bounded work), so presence can never hold up a stop."""
        presence = classify_presence(payload)
        if presence is Presence.OVERSIZED:
            self._ignore_oversized_presence(user, client_id, len(payload))
            return
        with self._lock:
            if not self.operators.record(user, client_id, presence, time.monotonic()):
                why = self.failsafe.operator_gone(user)
                if why and presence is Presence.SIGNED_OFF:
                    # a program that finished: the robot stops all the same, but nothing failed
                    self.trigger_stop(f"{why} (signed off)", level=logging.INFO)
                elif why:
                    self.trigger_stop(f"{why} (last-will)")

    def _ignore_oversized_presence(self, user: str, client_id: str, size: int) -> None:
        """Say once per client (and for a bounded number of clients) that its presence bodies are ignored."""
        key = (user, client_id)
        if key in self._oversized_presence or len(self._oversized_presence) >= MAX_OVERSIZED_LOGGED:
            return
        self._oversized_presence.add(key)
        reason = (f"ignored an oversized presence payload ({size} bytes, limit {MAX_PRESENCE_BYTES}) from "
                  f"{user}/{client_id}: it does not count as a heartbeat")
        log.warning("%s", reason)
        self.refuse(user, self.topics.operator(user, client_id), reason, client_id=client_id)

    def handle_command(self, user: str, topic: str, rule: Inbound, payload: bytes,
                       arrived: float | None = None) -> None:
        """Decode, check and execute one command (paho thread); motion that waited too long here is dropped."""
        message_id = sequence = sender = None  # sender: the client id the request names, for error reports
        preset = rule.spec.name if rule.spec is not None else None
        try:
            if rule.spec is not None:
                envelope = decode(payload, rule.spec.message_id)
                message_id, sequence, sender = envelope.message_id, envelope.sequence_number, envelope.client_id
                msg = rule.build(envelope.payload)
            else:
                body = loads(payload)
                sender = pop_generic_sender(body)  # '$client_id' is not a field of the ROS message
                msg = rule.build(body)
            if rule.is_velocity:
                make_safe_twist(msg, rule.limits)
        except (ProtocolError, ConversionError, CommandRefused, UnsafeCommand) as err:
            self.refuse(user, topic, str(err), message_id, sequence, payload=payload)
            return
        with self._lock:
            if preset != "emergency_stop" and not self.operators.is_live(user):
                self.refuse(user, topic, f"no live operator heartbeat from '{user}': publish a retained heartbeat "
                                         f"on {self.topics.operator(user, '<client_id>')} every second",
                            message_id, sequence, client_id=sender)
                return
            if rule.is_velocity or preset in GOAL_PRESETS:
                if self.motion_blocked:
                    self.refuse(user, topic, f"{self.motion_blocked}: send cmd/arm to resume", message_id, sequence,
                                client_id=sender)
                    return
                late = late_motion(arrived, time.monotonic(), self.robot.bridge.command_timeout,
                                   stop=rule.is_velocity and is_standstill(msg))
                if late:
                    self.refuse(user, topic, late, message_id, sequence, client_id=sender)
                    return
            # The number is recorded only once every other check has passed: a command refused for its body,
            # for missing presence or for blocked motion must not use it up, or the same command resent once
            # the gate opens would be dropped as a duplicate. A stop is never "too old" to obey.
            if sequence is not None and preset != "emergency_stop":
                verdict = self.sequences.check((user, rule.rule.mqtt_topic), sequence)
                if not verdict.accepted:
                    self.refuse(user, topic, f"{verdict.value} sequence_number {sequence} dropped",
                                message_id, sequence, client_id=sender)
                    return
            if rule.is_velocity or preset in GOAL_PRESETS:
                self._stop_repeats_left = 0  # a live operator commands again: the stop hold ends
                if rule.is_velocity:
                    self.failsafe.velocity_command(user, time.monotonic())
                else:
                    self.failsafe.goal_command(user)
            if preset == "emergency_stop":
                self.block_motion(f"emergency stop by {user}")
            elif preset == "disarm":
                self.block_motion(f"disarmed by {user}")
            elif preset == "arm" and not rule.is_service:
                self.motion_blocked = None
            self.owner = user
            if rule.is_service:
                self._call_command_service(user, topic, rule, msg, message_id, sequence, sender)
            elif rule.rule.on_demand:
                self.on_demand.publish(user, rule.rule.mqtt_topic, msg)
            else:
                self.publishers_by_rule[rule.rule.mqtt_topic].publish(msg)

    def _call_command_service(self, user: str, topic: str, rule: Inbound, request: Any, message_id: int | None,
                              sequence: int | None, sender: str | None = None) -> None:
        """Carry out a preset command through a ROS service; the outcome is acknowledged on state/ack."""
        client = self.command_services[rule.rule.mqtt_topic]
        if not client.service_is_ready():
            self.refuse(user, topic, f"service not available: {rule.rule.ros_topic} ({rule.rule.ros_type})",
                        message_id, sequence, client_id=sender)
            return
        future = client.call_async(request)
        deadline = time.monotonic() + COMMAND_SERVICE_TIMEOUT
        self._service_commands[future] = (deadline, rule.spec.name, message_id, sequence, rule.rule.ros_topic)
        future.add_done_callback(self._command_service_done)

    def _command_service_done(self, future: Any) -> None:
        with self._lock:
            entry = self._service_commands.pop(future, None)
        if entry is None:  # already acknowledged as a timeout
            return
        _, preset, message_id, sequence, service = entry
        response = future.result() if not future.cancelled() and future.exception() is None else None
        ok = response is not None and getattr(response, "success", True)
        if ok and preset == "arm":
            with self._lock:
                self.motion_blocked = None
        text = getattr(response, "message", "") if response is not None else f"{service} failed"
        self.publish_ack(message_id or 0, sequence, AckResult.ACCEPTED if ok else AckResult.FAILED,
                         text or f"{preset} {'done' if ok else 'failed'}")

    def _expire_command_services(self, now: float) -> None:
        with self._lock:
            late = [(f, e) for f, e in self._service_commands.items() if now > e[0]]
            for future, _ in late:
                del self._service_commands[future]
        for future, (_, preset, message_id, sequence, service) in late:
            future.cancel()
            self.publish_ack(message_id or 0, sequence, AckResult.FAILED,
                             f"{preset}: {service} did not answer within {COMMAND_SERVICE_TIMEOUT:g} s")

    def block_motion(self, reason: str) -> None:
        """Zero every velocity output and refuse motion until an operator arms again."""
        with self._lock:
            self.motion_blocked = reason
            self.failsafe.stopped()
            self._publish_zero_velocity()
        log.warning("motion blocked on %s: %s", self.robot.name, reason)

    def refuse(self, user: str, topic: str, reason: str, message_id: int | None = None,
               sequence: int | None = None, *, payload: bytes | None = None, client_id: str | None = None) -> None:
        """Report a refused input on ``to/<user>/error``, addressed to the program that sent it.

        Every program of ``user`` reads that topic, so the report repeats the sender's client id: given
        (``client_id``), or read from the refused ``payload`` here, on the rare refusal path rather than for
        every accepted command. A request that names no sender gets a report without one (any program may show it).
        """
        if client_id is None and payload is not None:
            client_id = sender_id(payload)
        log.debug("refused %s: %s", topic, reason)
        self.link.publish(self.topics.error(self.robot.name, user),
                          error_reply(topic, reason, message_id=message_id, sequence_number=sequence,
                                      client_id=client_id), qos=1)
