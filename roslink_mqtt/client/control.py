"""Who drives a robot, from the SDK: read ``state/control``, claim, release or take over the control lease, and stop
every robot at once. Used by :class:`~roslink_mqtt.client.robot_client.RobotClient` (its methods of the same names);
the bridge's side is ``roslink_mqtt/bridge/core/lease.py`` (docs/protocol.md, "Control").
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..protocol import AckResult, MessageId, ProtocolError, decode
from ..protocol.lease import CONTROL, ControlOp, ControlState, control_request
from ..topics import Verb, join_leaf
from .errors import CommandRefused, RobotError, RoslinkError, WaitTimeout

if TYPE_CHECKING:
    from .robot_client import RobotClient
    from .waiters import ErrorWaiters

STOP_ACK_WAIT = 1.0  # s: a robot that does not acknowledge an emergency stop within this is reported


@dataclass(frozen=True, slots=True)
class StopReport:
    """What :meth:`RobotClient.emergency_stop_all` learned about one robot."""

    robot: str
    acknowledged: bool  # the robot's bridge said it carried out the stop (state/ack) in time
    seconds: float | None = None  # from sending to its acknowledgement
    error: str | None = None  # why the stop could not be sent, or what the robot answered instead

    def line(self) -> str:
        """``turtle1   stopped (acknowledged in 0.012 s)``, as ``roslink-mqtt estop`` prints it."""
        if self.acknowledged:
            return f"{self.robot:<12} stopped (acknowledged in {self.seconds:.3f} s)"
        return f"{self.robot:<12} NOT ACKNOWLEDGED: {self.error or 'no answer'} — stop it another way"


def read_control(retained: Callable[[str, str, str, float], bytes | None], robot: str,
                 timeout: float) -> ControlState | None:
    """The robot's retained ``state/control``; None when none comes (an older bridge, or one not yet connected)."""
    payload = retained(robot, CONTROL, "control state", timeout)
    return None if payload is None else ControlState.from_json(payload)


def request_control(client: RobotClient, robot: str, op: ControlOp, timeout: float, *,
                    refusal: Callable[[str, Verb, str], str | None], send: Callable[[str, bytes, int, str], object],
                    errors: ErrorWaiters) -> ControlState:
    """Send ``control/<op>`` and wait for its outcome: the new ``state/control``, or CommandRefused with the reason
    (held by someone else, a viewer, no presence); WaitTimeout when the robot says nothing. ``refusal``, ``send``
    and ``errors``: the client's own (why the access report refuses, how it publishes, who waits for refusals)."""
    client.connection.require(f"control/{op.value} of {robot}")
    client.watch(robot)
    me, topic = client.username, client.topics.control(robot, client.username, op.value)
    refused = refusal(robot, Verb.CONTROL, op.value)
    if refused is not None:  # a viewer: the broker would drop the request without a word
        raise CommandRefused(RobotError(robot, topic, refused, client_id=client.client_id))
    done, box = threading.Event(), []
    sent = [False]

    def settled(state: ControlState) -> bool:
        return state.holder != me if op is ControlOp.RELEASE else state.holder == me

    def on_state(_topic: str, payload: bytes, _retained: bool) -> None:
        try:
            state = ControlState.from_json(payload) if payload else None
        except ProtocolError:
            return
        if state is not None and sent[0] and settled(state):
            box.append(state)
            done.set()

    state_topic = client.topics.state(robot, CONTROL)
    with errors.waiting(topic, done=done) as waiter:  # a refusal and the new state both end the wait
        try:
            client.connection.subscribe(state_topic, on_state, timeout=timeout)
            sent[0] = True
            send(topic, control_request(client.client_id), 1, join_leaf(Verb.CONTROL, op.value))
            if not done.wait(timeout):
                raise WaitTimeout(f"{robot} did not answer control/{op.value} within {timeout:g} s (is it online, "
                                  "and its bridge recent enough to have control leases?)")
            if waiter.errors:
                raise CommandRefused(waiter.errors[0])
            return box[0]
        finally:
            client.connection.unsubscribe(state_topic, on_state)


def stop_all(client: RobotClient, robots: list[str], reason: str, timeout: float) -> dict[str, StopReport]:
    """Send every robot an emergency stop at once, then wait up to ``timeout`` for each acknowledgement.

    Acknowledgements are kept as they come (paho's thread) and matched to the stops' sequence numbers here: a lock
    held while sending would make the network thread wait, and with it the SUBACKs the sends may wait for."""
    seen: dict[str, dict[int, float]] = {robot: {} for robot in robots}  # robot → {acknowledged sequence: when}
    sequences: dict[str, int | None] = {}
    sent_at: dict[str, float] = {}
    errors: dict[str, str] = {}
    changed = threading.Condition()

    def on_ack(robot: str) -> Callable[[str, bytes, bool], None]:
        def handle(_topic: str, payload: bytes, _retained: bool) -> None:
            try:
                body = decode(payload, MessageId.ACK).payload
            except ProtocolError:
                return
            if body["command"] == int(MessageId.EMERGENCY_STOP) and body["result"] == int(AckResult.ACCEPTED):
                with changed:
                    seen[robot].setdefault(body["command_sequence"], time.monotonic())
                    changed.notify_all()
        return handle

    def acked(robot: str) -> float | None:
        seq = sequences.get(robot)
        return None if seq is None else seen[robot].get(seq)

    handlers = {robot: on_ack(robot) for robot in robots}
    ack_topics = {robot: client.topics.state(robot, "ack") for robot in robots}
    try:
        for robot in robots:  # acknowledgements are not retained: listen first (a SUBACK away on a LAN)
            client.connection.subscribe(ack_topics[robot], handlers[robot], timeout=timeout)
        for robot in robots:
            sent_at[robot] = time.monotonic()
            try:
                # no PUBACK wait per robot: the next robot's stop must not queue behind it; the robot's own
                # acknowledgement below is the stronger confirmation
                sequences[robot] = client.command(robot, "emergency_stop", {"reason": reason})
            except (RoslinkError, ProtocolError) as err:  # one robot's failure must not keep the others running
                errors[robot] = str(err)
        deadline = time.monotonic() + timeout
        with changed:
            while any(acked(r) is None and r not in errors for r in robots) and time.monotonic() < deadline:
                changed.wait(deadline - time.monotonic())
    finally:
        for robot in robots:
            client.connection.unsubscribe(ack_topics[robot], handlers[robot])
    out = {}
    for robot in robots:
        at = acked(robot)
        if at is not None:
            out[robot] = StopReport(robot, True, max(0.0, at - sent_at[robot]))
        else:
            out[robot] = StopReport(robot, False, error=errors.get(robot, f"no acknowledgement within {timeout:g} s"))
    return out
