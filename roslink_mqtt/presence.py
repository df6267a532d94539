"""Operator presence (docs/safety.md, "Presence"): who is alive, decided from retained heartbeats and last-wills.

An operator client publishes a retained heartbeat on
``roslink/operators/<user>/<client_id>`` about once a second; its last-will
is an empty retained message, which clears it. The tracker here is pure
logic so the bridge's safety decisions can be unit-tested without a broker.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum

from .protocol import Envelope, MessageId, ProtocolError, RobotType, SystemStatus, decode, encode

DEFAULT_OPERATOR_PERIOD = 1.0  # s between operator heartbeats
# A heartbeat is ~200 bytes. Anything much larger is not one, and parsing megabytes of JSON on the bridge's
# MQTT thread (the thread that carries commands) would delay every command queued behind it.
MAX_PRESENCE_BYTES = 1024


class Presence(Enum):
    """What one message on an operator topic says, decided before any lock is taken."""

    GONE = "gone"  # empty: the last-will, or the clear that follows a sign-off
    SIGNED_OFF = "signed_off"  # a heartbeat saying POWEROFF: the client is leaving on purpose (before its clear)
    COMMANDING = "commanding"
    WATCHING = "watching"
    OVERSIZED = "oversized"  # larger than MAX_PRESENCE_BYTES: ignored unread, not a heartbeat


def operator_heartbeat(user: str, client_id: str, sequence_number: int = 0, *, commanding: bool = True) -> bytes:
    """The payload an operator publishes (a ROSLink heartbeat naming the client).

    ``system_status`` says what the client does: ACTIVE (4) — it commands robots;
    STANDBY (3) — it only watches or provides services. Robots stop when a
    commanding client of the driving user goes away, even if that user has
    other clients still connected.
    """
    status = SystemStatus.ACTIVE if commanding else SystemStatus.STANDBY
    payload = {"type": int(RobotType.GENERIC), "name": client_id, "system_status": int(status),
               "owner_id": user, "mode": 0}
    return encode(Envelope(MessageId.HEARTBEAT, payload, 0, sequence_number))


def operator_signoff(user: str, client_id: str, sequence_number: int = 0) -> bytes:
    """What a client publishes (not retained) just before clearing its heartbeat on a clean exit.

    The clear (an empty retained message) is byte for byte what the last-will of a crashed client
    publishes, so without this the bridge cannot tell a program that finished from one that died:
    every clean exit after a command read as a failure in its log. The robot still stops when the
    client drove it (the presence rule does not change); only the report does.
    """
    payload = {"type": int(RobotType.GENERIC), "name": client_id, "system_status": int(SystemStatus.POWEROFF),
               "owner_id": user, "mode": 0}
    return encode(Envelope(MessageId.HEARTBEAT, payload, 0, sequence_number))


def _status(payload: bytes) -> int | None:
    try:
        return decode(payload, MessageId.HEARTBEAT).payload.get("system_status")
    except ProtocolError:
        return None


def is_commanding(payload: bytes) -> bool:
    """Whether a non-empty operator heartbeat comes from a commanding client.

    Only a ROSLink heartbeat that says STANDBY is a mere watcher; anything
    else (a Node-RED flow sending ``1``, another status) counts as commanding:
    when unsure, losing the client stops the robot.
    """
    return _status(payload) != SystemStatus.STANDBY


def classify_presence(payload: bytes, max_bytes: int = MAX_PRESENCE_BYTES) -> Presence:
    """Classify an operator-topic payload; the size is checked before a single byte is parsed.

    An oversized body is not a heartbeat: a client that only sends those
    expires like a silent one, so a flood of them can neither keep a client
    alive nor cost the bridge more than a length check.
    """
    if not payload:
        return Presence.GONE
    if len(payload) > max_bytes:
        return Presence.OVERSIZED
    status = _status(payload)
    if status == SystemStatus.POWEROFF:
        return Presence.SIGNED_OFF
    return Presence.WATCHING if status == SystemStatus.STANDBY else Presence.COMMANDING


@dataclass
class OperatorTracker:
    """Live operator clients: when each was last heard of and whether it commands."""

    timeout: float
    _seen: dict[tuple[str, str], tuple[float, bool]] = field(default_factory=dict)

    def heartbeat(self, user: str, client_id: str, payload: bytes, now: float) -> bool:
        """Classify and record one message on an operator topic (see :meth:`record`)."""
        return self.record(user, client_id, classify_presence(payload), now)

    def record(self, user: str, client_id: str, presence: Presence, now: float) -> bool:
        """Record an already classified message; False when ``user`` just lost command presence.

        Split from parsing so the bridge can classify outside its command lock.
        GONE is the last-will or a clean sign-off's clear; SIGNED_OFF counts as
        GONE here (the caller tells the two apart). Command presence is lost
        when a commanding client leaves, or when the user's last client does;
        a watcher leaving while others stay changes nothing. OVERSIZED changes
        nothing at all.
        """
        key = (user, client_id)
        if presence is Presence.OVERSIZED:
            return True
        if presence is not Presence.GONE and presence is not Presence.SIGNED_OFF:
            self._seen[key] = (now, presence is Presence.COMMANDING)
            return True
        gone = self._seen.pop(key, None)
        return not ((gone is not None and gone[1]) or not self.is_live(user))

    def expire(self, now: float) -> list[str]:
        """Forget clients silent for longer than ``timeout``; return users who lost command presence."""
        stale = [key for key, (at, _) in self._seen.items() if now - at > self.timeout]
        lost = set()
        for key in stale:
            _, commanding = self._seen.pop(key)
            if commanding:
                lost.add(key[0])
        lost |= {user for user, _ in stale if not self.is_live(user)}
        return sorted(lost)

    def is_live(self, user: str, client_id: str | None = None) -> bool:
        """Any client of ``user`` live, or that one client when ``client_id`` is given."""
        if client_id is not None:
            return (user, client_id) in self._seen
        # tuple(): one atomic copy, as the executor asks while paho's thread may be recording
        return any(u == user for u, _ in tuple(self._seen))

    def live_users(self) -> set[str]:
        return {u for u, _ in tuple(self._seen)}

    def clients(self) -> Iterable[tuple[str, str]]:
        return list(self._seen)
