"""The bridge's command endpoint: topic and bytes in → a refusal out, or one thing for ROS to carry out. ROS-free.

Everything a user sends the robot passes here: parse the topic (:mod:`roslink_mqtt.topics`), authorize
(:mod:`roslink_mqtt.authorize`), decode and validate the body, make velocities safe, then the gates — operator presence,
motion blocked by an emergency stop or a disarm, motion that waited too long inside the bridge — and the
sequence rule (stale and duplicate numbers are dropped; a number is recorded only once every other check has
passed). State-changing inputs also need the control lease (:mod:`.lease`: one driver at a time; an emergency
stop needs none, and any granted user may send one). What survives becomes a call on :class:`Actuators`; what does
not becomes an error report on ``to/<user>/error``. Presence, the failsafe decisions, stops, acknowledgements, the
lease and the robot's heartbeat live here too, because they read and change the same motion state under one lock.

The ROS side (:mod:`.node`) owns publishers, service clients and timers and implements :class:`Actuators`;
the MQTT side is any object with ``publish``. So the endpoint runs in-process in unit tests with a recording
link and recording actuators (``tests/unit/test_bridge_endpoint.py``), the way rosbridge tests one capability with a
real protocol object, while the integration tests keep running the real bridge.

Threads: MQTT messages arrive on paho's network thread, supervision and ROS callbacks on the executor.
``lock`` serialises everything that touches motion state, so a stop and a command never interleave.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace
from typing import Any, Protocol

from ...authorize import refusal
from ...config import Fleet, Robot, Role
from ...presence import MAX_PRESENCE_BYTES, OperatorTracker, Presence, classify_presence
from ...protocol import (
    AckResult,
    Envelope,
    MessageId,
    SequenceTracker,
    SystemStatus,
    decode,
    encode,
    error_reply,
    loads,
    sender_id,
)
from ...protocol.control import ErrorReport, Notice, pop_generic_sender
from ...protocol.errors import ProtocolError
from ...protocol.lease import CONTROL, ControlOp, ControlState
from ...topics import Kind, TopicTree, Verb
from .capabilities import Capability, Control, Refusal, Request
from .claim import Claim
from .failsafe import Failsafe, late_motion
from .lease import ControlLease, Outcome
from .refusals import INPUT_REFUSALS, RefusalReports
from .routes import Inbound
from .safety import ClampNotices, is_standstill, make_safe_twist

log = logging.getLogger("roslink_mqtt.bridge")

SUPERVISION_RATE = 20.0  # Hz: failsafe checks, stop repeats, link check
MAX_OVERSIZED_LOGGED = 256  # presence clients whose oversized payloads are logged (once each)
ACK_QOS = 1  # state/ack: the outcome of a command (and every failsafe stop) must not be lost
STOP_ACK_INTERVAL = 0.5  # s: a user's emergency stops are acknowledged at most this often (every one is obeyed)
# A robot file's bridge before the broker's grants (protocol/grants.py) arrive: it knows nobody, so nobody may do
# anything; the refusal says what is missing and who supplies it.
NO_GRANTS_YET = ("{robot} has no grants from the broker yet, so it obeys nobody: the fleet's administrators "
                 "publish them (`roslink-mqtt fleet apply`; the embedded broker does at start)")
MAX_QUEUE_ALLOWANCE = 1.0  # s a heartbeat's PUBACK may take beyond link_timeout because of a busy uplink or downlink


class Link(Protocol):
    """The MQTT side: :class:`~roslink_mqtt.bridge.core.link.MqttLink`, or a recording stand-in in tests."""

    connected: threading.Event

    def queue_delay(self) -> float:
        """Seconds a message handed over now waits in the network before the broker has it (0: unknown)."""
        ...

    def heard_at(self) -> float:
        """``time.monotonic()`` when the broker's last message reached the bridge (0.0: none yet)."""
        ...

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> Any: ...


class Actuators(Protocol):
    """The ROS side: what the endpoint asks to be carried out (bridge/ros/node.py implements it with rclpy)."""

    def publish(self, user: str, route: Inbound, msg: Any) -> None:
        """Publish ``msg`` on the route's ROS topic (on-demand routes: through the user's publisher)."""

    def call_service(self, route: Inbound, request: Any, message_id: int | None, sequence: int | None) -> str | None:
        """Call the route's ROS service; the outcome is acknowledged later. A reason if it cannot be called now."""

    def zero_velocity(self) -> None:
        """Publish a zero velocity on every velocity output."""

    def failsafe_actions(self) -> None:
        """Publish the fleet file's ``bridge.on_failsafe`` messages."""

    def cancel_goals(self, user: str | None, reason: str) -> int:
        """Cancel the action goals of ``user`` (None: of everyone), results saying ``reason``; how many."""




class CommandEndpoint:
    """Decides what to do with every input of one robot, and keeps its motion state."""

    def __init__(self, fleet: Fleet, robot: Robot, link: Link, actuators: Actuators,
                 routes: Mapping[str, Inbound], *, claim: Claim | None = None,
                 capabilities: Iterable[Capability[Any]] = (),
                 clock: Callable[[], float] = time.monotonic) -> None:
        """``routes``: compiled mqtt_to_ros rules by leaf (``cmd/twist``); ``capabilities``: every other verb a user
        sends (bridge/core/capabilities/; the lease verbs are the endpoint's own); ``claim``: this bridge's, carried by
        every heartbeat (bridge/core/claim.py); ``clock``: the monotonic clock of every timer here and of the links'
        arrival times (a test's own, to step time instead of sleeping)."""
        self.clock = clock
        self.fleet, self.robot, self.topics = fleet, robot, TopicTree(fleet.prefix)
        self.link, self.actuators, self.routes = link, actuators, dict(routes)
        # every verb but cmd/* runs through _dispatch: parse, gate, run (bridge/core/capabilities/)
        self.capabilities: dict[Verb, Capability[Any]] = {Verb.CONTROL: Control(robot.name, self, self.refuse)}
        self.capabilities.update((c.verb, c) for c in capabilities)
        settings = robot.bridge
        self.claim = claim or Claim.mine()
        self.session = int(self.claim.since) & 0xFFFFFFFF  # grows with every start
        self.fenced: str | None = None  # why this bridge stood down for another one: it ignores every input
        self.lease = ControlLease(robot.name, robot.control, frozenset(robot.supervisors))  # who drives
        self.motion_blocked: str | None = None  # why motion is refused (e-stop, disarmed)
        self.on_failsafe_stop: Callable[[str], None] | None = None  # after each failsafe stop (the snapshot's)
        self.sequences = SequenceTracker()
        self.operators = OperatorTracker(settings.operator_timeout)
        self.failsafe = Failsafe(settings.command_timeout)
        self.clamp_notices = ClampNotices(settings.command_timeout)  # streams told that the robot clamps them
        self.lock = threading.RLock()
        # sequence numbers: heartbeats and acks are sent from paho's and the executor's threads; next() on an
        # itertools.count is one C call (atomic), where `n += 1` on an attribute could hand out a number twice
        self._heartbeat_numbers, self._ack_numbers = itertools.count(1), itertools.count(1)
        # (deadline for its PUBACK, sent at, paho info): link_timeout after it, plus what it waits behind
        self._pending_heartbeat: tuple[float, float, Any] | None = None
        self._stop_repeats_left = 0
        self._oversized_presence: set[tuple[str, str]] = set()  # clients already told (paho threads; set.add is atomic)
        self._grants: tuple[Fleet, dict[str, Role | None]] = (fleet, {})  # swapped whole on reload
        self.reports = RefusalReports()  # refusal reports per user are rate-limited, never silently dropped
        self._stop_acked: dict[str, float] = {}  # user → when their last emergency stop was acknowledged

    # -- grants --------------------------------------------------------------------------
    def role_of(self, user: str) -> Role | None:
        """The user's role on this robot, computed once per user and fleet version (any thread)."""
        fleet, cache = self._grants  # one read: a reload swaps both at once
        try:
            return cache[user]
        except KeyError:
            role = cache[user] = fleet.roles_of(user).get(self.robot.name)
            return role

    def set_fleet(self, fleet: Fleet) -> list[str]:
        """Apply a re-read fleet file's grants; stop the robot if its motion owner lost operator rights.

        Returns the users demoted from operator (the ROS side withdraws what they provide).
        """
        before, after = self.fleet.users_of(self.robot.name), fleet.users_of(self.robot.name)
        robot = fleet.robots.get(self.robot.name, self.robot)
        with self.lock:
            self.fleet, self._grants = fleet, (fleet, {})
            # who drives and who may stop are grants too: they apply now (rules and settings need a restart)
            self.robot = replace(self.robot, control=robot.control, supervisors=robot.supervisors, estop=robot.estop)
            self.lease.mode, self.lease.supervisors = robot.control, frozenset(robot.supervisors)
        demoted = sorted(u for u, role in before.items() if role is Role.OPERATOR and after.get(u) is not Role.OPERATOR)
        for user in demoted:
            with self.lock:
                self._lease_ends(user, "operator grant removed")
                why = self.failsafe.operator_gone(user)
                if why:
                    self.trigger_stop(f"{why} (operator grant removed)")
            self._cancel_goals(user, f"{user} is no longer an operator of {self.robot.name}")
        return demoted

    # -- MQTT in (paho network thread) ----------------------------------------------------
    def on_mqtt(self, topic: str, payload: bytes, retained: bool = False, arrived: float | None = None) -> None:
        """One MQTT message; ``arrived`` (monotonic, from the link) lets late motion be dropped, not executed."""
        if self.fenced is not None:
            return  # another bridge has the robot: nothing reaches ROS from here any more
        parsed = self.topics.parse(topic)
        if parsed is None:
            return
        if parsed.kind is Kind.OPERATOR:
            self.on_operator(parsed.user or "", parsed.client_id or "", payload)
            return
        if parsed.kind is not Kind.FROM or parsed.robot != self.robot.name or not parsed.user:
            return
        user, verb = parsed.user, parsed.verb
        if self._grants[0].grants_pending:
            if payload:  # (an empty retained message withdraws an offer: nothing to refuse)
                self.refuse(user, topic, NO_GRANTS_YET.format(robot=self.robot.name), payload=payload)
            return
        if retained and not (verb is not None and verb.retained_by_sender):
            # A retained command is replayed by the broker whenever the bridge (re)subscribes: executing it
            # would drive the robot on a stale order. Only offers and advertisements are meant to be retained.
            if payload:
                self.refuse(user, topic, "ignored a retained command from the broker: publish commands "
                                         "without the retain flag (and clear this one with an empty retained message)",
                            payload=payload)
            return
        capability = self.capabilities.get(verb) if verb is not None else None
        if capability is not None:
            self._dispatch(capability, user, parsed.name or "", topic, payload)
            return
        if verb is not None and verb is not Verb.CMD:
            self.refuse(user, topic, f"'{verb.value}' is not served by this bridge", payload=payload)
            return
        name = parsed.leaf
        route = self.routes.get(name)
        if route is None:
            self.refuse(user, topic, f"no mapping for '{name}' on robot {self.robot.name} "
                                     f"(commands: {', '.join(sorted(self.routes)) or 'none'})", payload=payload)
            return
        role = self.role_of(user)
        why = refusal(user, role, Verb.CMD, name, robot=self.robot.name)
        if why and role is Role.VIEWER and name in self.robot.estop_inputs and self.robot.estop == "viewers":
            why = None  # any granted user may stop the robot (robots.yaml `estop: operators` restricts it)
        if why:
            self.refuse(user, topic, why, payload=payload)
            return
        self.handle_command(user, topic, route, payload, arrived)

    def _dispatch(self, capability: Capability[Any], user: str, name: str, topic: str, payload: bytes) -> None:
        """Every verb with a capability, the same way: parse its body once, gate, then carry it out."""
        role = self.role_of(user)
        try:
            body = capability.parse(name, payload)
        except ProtocolError as err:
            capability.refuse(Request(user, name, topic, payload, None, role),
                              Refusal(str(err), request_id=err.request_id, client_id=err.client_id))
            return
        request = Request(user, name, topic, payload, body, role)
        # an operation that may move the robot (MOVES_ROBOT) is gated and handed over under the motion lock, so an
        # emergency stop is either before it (the gate refuses) or after it (the stop cancels it), never between
        with self.lock if getattr(capability, "MOVES_ROBOT", False) else contextlib.nullcontext():
            refused = capability.gate(request, self)
            if refused is None:
                capability.run(request)
        if refused is not None:
            capability.refuse(request, refused)

    # -- Gates and LeaseDesk (bridge/core/capabilities/): what capabilities ask of the robot's state ----------------
    def is_live(self, user: str) -> bool:
        return self.operators.is_live(user)

    def lease_gate(self, user: str) -> str | None:
        with self.lock:
            return self._lease_gate(user)

    def tell_displaced(self, user: str, text: str) -> None:
        self.link.publish(self.topics.error(self.robot.name, user),
                          error_reply(self.topics.state(self.robot.name, CONTROL), text), qos=ErrorReport.QOS)

    def cancel_goals(self, user: str | None, why: str) -> None:
        self._cancel_goals(user, why)

    # -- the control lease (bridge/core/lease.py) --------------------------------------------------
    def _lease_gate(self, user: str, *, claim: bool = True) -> str | None:
        """Under the lock: None when ``user`` may change the robot now (a free lease is claimed on the way unless
        ``claim`` is False)."""
        before = self.lease.version
        why = self.lease.gate(user, live=self.operators.is_live(user), now=time.time(), claim=claim)
        if self.lease.version != before:
            log.info("%s: %s", self.robot.name, self.lease.event)
            self.publish_control()
        return why

    # -- a VDA 5050 master control's lease (bridge/ros/vda5050_node.py) ------------------------------
    def hold_for_order(self, user: str) -> str | None:
        """``user``, a robot's VDA 5050 master control, takes the free lease for an order (or keeps it); else why
        not. An order never takes the lease over from someone else. The master sends no ROSLink presence: its lease
        lasts while its order does (:meth:`release_after_order`), and any granted user's stop still stops it."""
        with self.lock:
            if self.fenced:
                return self.fenced
            if self.lease.holder not in (None, user):
                return f"{self.robot.name} is {self.lease.driven_by()}"
            before = self.lease.version
            answer = self.lease.request(user, ControlOp.CLAIM, live=True, now=time.time())
            if self.lease.version != before:
                log.info("%s: %s (VDA 5050 order)", self.robot.name, self.lease.event)
                self.publish_control()
            return None if answer.outcome is not Outcome.REFUSED else answer.reason

    def release_after_order(self, user: str, why: str) -> None:
        """The master control's order ended (finished, cancelled, refused): so does its lease, if it held one."""
        with self.lock:
            self._lease_ends(user, why)

    def holder(self) -> str | None:
        return self.lease.holder

    def control_state(self) -> ControlState:
        return self.lease.state(self.robot.estop, self.motion_blocked or "")

    def publish_control(self) -> None:
        """Retained ``state/control``: who holds control, since when (on every change, and on connecting)."""
        self.link.publish(self.topics.state(self.robot.name, CONTROL), self.control_state().to_json(),
                          qos=ControlState.QOS, retain=True)

    def _lease_ends(self, user: str, why: str) -> None:
        """Under the lock: ``user``'s presence or grant ended; so does their lease, if they held it."""
        if self.lease.ended(user, why, time.time()):
            log.info("%s: %s", self.robot.name, self.lease.event)
            self.publish_control()

    def _cancel_goals(self, user: str | None, why: str) -> None:
        """Cancel goals exactly where velocity stops (presence ended, broker lost, e-stop); say so on state/ack."""
        count = self.actuators.cancel_goals(user, why)
        if count:
            whose = f" of {user}" if user else ""
            self.publish_ack(0, None, AckResult.FAILSAFE, f"canceled {count} action goal(s){whose}: {why}")

    def handle_command(self, user: str, topic: str, route: Inbound, payload: bytes,
                       arrived: float | None = None) -> None:
        """Decode, check and carry out one command; motion that waited too long in the bridge is dropped."""
        message_id = sequence = sender = None  # sender: the client id the request names, for error reports
        clamped: str | None = None  # what the velocity limits cut, for the sender's notice
        behaviour = route.behaviour
        try:
            if route.spec is not None:
                envelope = decode(payload, route.spec.message_id)
                message_id, sequence, sender = envelope.message_id, envelope.sequence_number, envelope.client_id
                msg = route.build(envelope.payload)
            else:
                body = loads(payload)
                sender = pop_generic_sender(body)  # '$client_id' is not a field of the ROS message
                msg = route.build(body)
            if route.is_velocity:
                clamped = make_safe_twist(msg, route.limits)
        except INPUT_REFUSALS as err:  # the sender: the envelope's or body's, as far as parsing got (never re-parsed)
            self.refuse(user, topic, str(err), message_id, sequence,
                        client_id=sender if sender is not None else getattr(err, "client_id", None))
            return
        with self.lock:
            if not behaviour.never_stale and not self.operators.is_live(user):
                self.refuse(user, topic, f"no live operator heartbeat from '{user}': publish a retained heartbeat "
                                         f"on {self.topics.operator(user, '<client_id>')} every second",
                            message_id, sequence, client_id=sender)
                return
            if not behaviour.never_stale:  # an emergency stop needs no lease
                why = self._lease_gate(user, claim=False)  # claimed below, once every other check has passed
                if why:
                    self.refuse(user, topic, why, message_id, sequence, client_id=sender)
                    return
            standstill = route.is_velocity and is_standstill(msg)  # a zero twist: the operator stopping the robot
            if route.moves_robot:
                if self.motion_blocked:
                    self.refuse(user, topic, f"{self.motion_blocked}: send cmd/arm to resume", message_id, sequence,
                                client_id=sender)
                    return
                late = late_motion(arrived, self.clock(), self.robot.bridge.command_timeout,
                                   stop=standstill)
                if late:
                    self.refuse(user, topic, late, message_id, sequence, client_id=sender)
                    return
            # The number is recorded only once every other check has passed: a command refused for its body,
            # for missing presence or for blocked motion must not use it up, or the same command resent once
            # the gate opens would be dropped as a duplicate. A stop is never "too old" to obey.
            if sequence is not None and not behaviour.never_stale:
                verdict = self.sequences.check((user, route.name), sequence)
                if not verdict.accepted:
                    self.refuse(user, topic, f"{verdict.value} sequence_number {sequence} dropped",
                                message_id, sequence, client_id=sender)
                    return
            if not behaviour.never_stale:
                self._lease_gate(user)  # a free lease is this command's sender's now (auto mode)
            if route.moves_robot:
                self._stop_repeats_left = 0  # a live operator commands again: the stop hold ends
                if route.is_velocity:
                    self.failsafe.velocity_command(user, self.clock(), standstill=standstill)
                else:
                    self.failsafe.goal_command(user)
            self._carry_out(user, topic, route, msg, Notice(topic, clamped or "", message_id, sequence, sender),
                            clamped=clamped is not None, standstill=standstill)

    def _carry_out(self, user: str, topic: str, route: Inbound, msg: Any, told: Notice, *, clamped: bool,
                   standstill: bool) -> None:
        """A command that passed every check: block or resume motion, publish it or call its service, tell the
        sender what the limits cut (``told``: its ids, and the cut), acknowledge a stop. Under the lock."""
        behaviour, message_id, sequence, sender = route.behaviour, told.message_id, told.sequence_number, told.client_id
        if behaviour.blocks_motion:
            self.block_motion(f"{behaviour.blocks_motion} by {user}")
        elif behaviour.resumes_motion and not route.is_service:
            self._set_blocked(None)  # a service-backed arm resumes only when its service succeeds
        if route.is_service:
            why = self.actuators.call_service(route, msg, message_id, sequence)
            if why:
                self.refuse(user, topic, why, message_id, sequence, client_id=sender)
        else:
            self.actuators.publish(user, route, msg)
            if route.is_velocity and self.clamp_notices.tell((user, sender or "", route.name), self.clock(),
                                                             clamped=clamped, standstill=standstill):
                self.notify(user, told)
        if behaviour.never_stale:  # a stop is acknowledged: `estop --all` reports which robots heard it
            self._acknowledge_stop(user, message_id, sequence, behaviour.blocks_motion or "stop")

    def _acknowledge_stop(self, user: str, message_id: int | None, sequence: int | None, what: str) -> None:
        """Acknowledge a stop on ``state/ack``, at most once per :data:`STOP_ACK_INTERVAL` per user: any granted
        user, viewers included, may send stops, and a flood of them must not become a flood of acknowledgements on
        the robot's uplink (control class: they would go out ahead of its state). Every stop is still obeyed."""
        now = self.clock()
        if now - self._stop_acked.get(user, -STOP_ACK_INTERVAL) < STOP_ACK_INTERVAL:
            return
        self._stop_acked[user] = now  # granted users only reach here: bounded by the fleet file
        self.publish_ack(message_id or 0, sequence, AckResult.ACCEPTED, f"{what} by {user}")

    def on_operator(self, user: str, client_id: str, payload: bytes) -> None:
        """Operator presence. Classified before the lock (bounded work), so presence can never hold up a stop."""
        presence = classify_presence(payload)
        if presence is Presence.OVERSIZED:
            self._ignore_oversized_presence(user, client_id, len(payload))
            return
        with self.lock:
            gone = not self.operators.record(user, client_id, presence, self.clock())
            if gone:
                if not self.operators.is_live(user):  # the lease is the user's: it ends with their last client
                    self._lease_ends(user, "signed off" if presence is Presence.SIGNED_OFF else "last-will")
                why = self.failsafe.operator_gone(user)
                if why and presence is Presence.SIGNED_OFF:
                    # a program that finished: the robot stops all the same, but nothing failed (result 0, INFO)
                    self.trigger_stop(f"{why} (signed off)", level=logging.INFO, result=AckResult.ACCEPTED)
                elif why:
                    self.trigger_stop(f"{why} (last-will)")
        if gone:
            ending = "signed off" if presence is Presence.SIGNED_OFF else "last-will"
            self._cancel_goals(user, f"operator {user} went away ({ending})")

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

    # -- motion state ------------------------------------------------------------------------
    def resume_motion(self) -> None:
        """A service-backed arm succeeded: motion may be commanded again."""
        with self.lock:
            self._set_blocked(None)

    def _set_blocked(self, reason: str | None) -> None:
        """Under the lock: why motion is refused now (None: it is not). ``state/control`` says so when motion becomes
        blocked or free again, so ``control status``, ``info``, ``monitor`` and the dashboard show an emergency stop
        where people look; not on every further stop while blocked (any granted user may send stops: two viewers
        taking turns must not turn them into a stream of retained messages on the robot's uplink)."""
        changed = (reason is None) != (self.motion_blocked is None)
        self.motion_blocked = reason
        if changed:
            self.publish_control()

    def block_motion(self, reason: str) -> None:
        """Zero every velocity output and refuse motion until an operator arms again."""
        with self.lock:
            self._set_blocked(reason)
            self.failsafe.stopped()
            self.actuators.zero_velocity()
        log.warning("motion blocked on %s: %s", self.robot.name, reason)
        self._cancel_goals(None, reason)

    def trigger_stop(self, reason: str, level: int = logging.WARNING, result: AckResult = AckResult.FAILSAFE) -> None:
        """Failsafe stop: zero velocity now and a few more times, run on_failsafe actions, tell users why.

        ``level`` INFO and ``result`` ACCEPTED are for stops that are the expected end of something (a client that
        signed off): the robot stops exactly the same way, but neither the log nor the acknowledgement cries
        failure (only a real failsafe is result 3).
        """
        with self.lock:
            self.failsafe.stopped()
            self.actuators.zero_velocity()
            self._stop_repeats_left = round(self.robot.bridge.stop_hold * SUPERVISION_RATE)
            self.actuators.failsafe_actions()
        log.log(level, "%s of %s: %s", "failsafe stop" if level >= logging.WARNING else "stop", self.robot.name,
                reason)
        self.publish_ack(0, None, result, reason)
        if result is AckResult.FAILSAFE and level >= logging.WARNING and self.on_failsafe_stop is not None:
            self.on_failsafe_stop(reason)  # the snapshot worker keeps the seconds before it (never blocks)

    def operator_gone(self, user: str, why_suffix: str) -> None:
        """Stop if ``user`` owned the motion (their presence ended, their grant went)."""
        with self.lock:
            why = self.failsafe.operator_gone(user)
            if why:
                self.trigger_stop(f"{why} ({why_suffix})")

    def fence(self, reason: str) -> None:
        """Another bridge has the robot (bridge/core/claim.py): stop it, and ignore every input from now on."""
        with self.lock:
            self.fenced = reason
            self.trigger_stop(reason)
        self._cancel_goals(None, reason)

    # -- the link ------------------------------------------------------------------------------
    def link_up(self) -> None:
        with self.lock:
            self.failsafe.link_up = True
            self._pending_heartbeat = None

    def link_down(self, reason: str, *, closing: bool) -> None:
        """The broker connection ended; ``closing``: our own shutdown, not a failure."""
        with self.lock:
            why = self.failsafe.link_lost()
            if why:
                if closing:
                    self.trigger_stop("the bridge is shutting down", level=logging.INFO)
                else:
                    self.trigger_stop(f"{why} ({reason})")
        self._cancel_goals(None, "the bridge is shutting down" if closing else f"lost the broker ({reason})")

    def _check_link(self, now: float) -> None:
        """A heartbeat not acknowledged within link_timeout means the broker stopped answering."""
        pending = self._pending_heartbeat
        if pending is None:
            return
        deadline, sent_at, info = pending
        try:
            published = info.is_published()
        except RuntimeError:  # paho: the publish itself failed (the connection was gone): never acknowledged, and
            self._pending_heartbeat = None  # the lost connection has its own path (link_down): nothing to wait for
            return
        if published:
            self._pending_heartbeat = None
            if not self.failsafe.link_up and self.link.connected.is_set():
                self.failsafe.link_up = True
                log.info("broker answers again")
        elif now > deadline and self.failsafe.link_up:
            if self._downlink_busy(now, sent_at):
                return
            why = self.failsafe.link_lost()
            log.warning("broker silent for %.2f s", now - sent_at)
            if why:
                self.trigger_stop(f"{why} (no answer for {now - sent_at:.2g} s)")

    def _downlink_busy(self, now: float, sent_at: float) -> bool:
        """The broker is talking, so its PUBACK is on the way behind what it sends: slow, not silent.

        Why: a broker writes its answers in order on one connection, and the bridge reads them in order on one
        thread. A viewer flooding parameter reads through a broker that does not pace him (Mosquitto) keeps the
        bridge busy (his requests on the viewer link, thousands of replies and refusals going out on the command
        link, their PUBACKs coming back on it): a clean-clone run read the heartbeat's PUBACK 0.5 s late, with
        alice's twists still arriving (p99 421 ms), and the robot stopped for "lost the broker". A broker heard
        from within link_timeout is not silent; the cap still stops the robot within link_timeout +
        MAX_QUEUE_ALLOWANCE of a broker that keeps sending but never answers, and a frozen broker stops being
        heard at once."""
        timeout = self.robot.bridge.link_timeout
        return now - self.link.heard_at() <= timeout and now <= sent_at + timeout + MAX_QUEUE_ALLOWANCE

    # -- supervision (executor, SUPERVISION_RATE) ------------------------------------------------
    def supervise(self, now: float) -> None:
        """Link check, operator expiry, the failsafe's timers, and the repeats of a stop."""
        with self.lock:
            self._check_link(now)
            expired = self.operators.expire(now)
            for user in expired:
                if not self.operators.is_live(user):
                    self._lease_ends(user, f"no heartbeat for {self.operators.timeout:g} s")
                why = self.failsafe.operator_gone(user)
                if why:
                    self.trigger_stop(f"{why} (no heartbeat for {self.operators.timeout:g} s)")
            why = self.failsafe.tick(now, self.operators.live_users())
            if why:
                self.trigger_stop(why)
            if self._stop_repeats_left > 0:
                self._stop_repeats_left -= 1
                self.actuators.zero_velocity()
        for user in expired:
            self._cancel_goals(user, f"operator {user} went away (no heartbeat for {self.operators.timeout:g} s)")
        for user, topic, reason in self.reports.summaries(now):
            self.link.publish(self.topics.error(self.robot.name, user), error_reply(topic, reason), qos=ErrorReport.QOS)

    # -- MQTT out --------------------------------------------------------------------------------
    def heartbeat(self, status: SystemStatus) -> bytes:
        sequence = next(self._heartbeat_numbers) & 0xFFFFFFFF
        payload = {"type": int(self.robot.type), "name": self.robot.name, "system_status": int(status),
                   "owner_id": self.lease.holder or "", "mode": 0, "session": self.session, **self.claim.fields()}
        return encode(Envelope(MessageId.HEARTBEAT, payload, self.robot.system_id, sequence))

    def publish_heartbeat(self) -> None:
        if self.fenced is not None:
            return  # the robot's heartbeat is the other bridge's now
        status = SystemStatus.EMERGENCY if self.motion_blocked else SystemStatus.ACTIVE
        info = self.link.publish(self.topics.heartbeat(self.robot.name), self.heartbeat(status), qos=1, retain=True)
        with self.lock:
            if info is not None and self._pending_heartbeat is None:
                # A thin uplink may hold the heartbeat behind data already in the network (at most the uplink's
                # budget, bridge/core/uplink.py): slow is not silent, so the wait for its PUBACK grows by that time,
                # capped so that a frozen broker still stops the robot within link_timeout + MAX_QUEUE_ALLOWANCE.
                now = self.clock()
                allowance = min(MAX_QUEUE_ALLOWANCE, max(0.0, self.link.queue_delay()))
                self._pending_heartbeat = (now + self.robot.bridge.link_timeout + allowance, now, info)

    def publish_ack(self, command: int, sequence: int | None, result: AckResult, text: str) -> None:
        sequence_number = next(self._ack_numbers) & 0xFFFFFFFF
        payload = {"command": int(command), "command_sequence": -1 if sequence is None else sequence,
                   "result": int(result), "text": text}
        self.link.publish(self.topics.state(self.robot.name, "ack"),
                          encode(Envelope(MessageId.ACK, payload, self.robot.system_id, sequence_number)),
                          qos=ACK_QOS)

    def notify(self, user: str, notice: Notice) -> None:
        """Tell ``user`` (the program the notice names) that what they sent was carried out, but changed.

        Published after the command reached ROS, so it never delays one; not an error report, because nothing was
        refused (a client waiting for refusals does not raise for it)."""
        log.debug("notice to %s about %s: %s", user, notice.topic, notice.notice)
        self.link.publish(self.topics.notice(self.robot.name, user), notice.to_json(), qos=Notice.QOS)

    def refuse(self, user: str, topic: str, reason: str, message_id: int | None = None,
               sequence: int | None = None, *, payload: bytes | None = None, client_id: str | None = None,
               request_id: str | int | None = None) -> None:
        """Report a refused input on ``to/<user>/error``, addressed to the program that sent it.

        Every program of ``user`` reads that topic, so the report repeats the sender's client id: given
        (``client_id``), or read from the refused ``payload`` here, on the rare refusal path rather than for
        every accepted command. A request that names no sender gets a report without one (any program may show it).
        """
        log.debug("refused %s: %s", topic, reason)
        admitted = self.reports.admit(user, topic, reason, self.clock())
        if admitted is None:
            return  # held back and counted: the next report (or a summary) says how many
        if client_id is None and payload is not None:
            client_id = sender_id(payload)
        self.link.publish(self.topics.error(self.robot.name, user),
                          error_reply(topic, admitted, message_id=message_id, sequence_number=sequence,
                                      client_id=client_id, request_id=request_id), qos=ErrorReport.QOS)
