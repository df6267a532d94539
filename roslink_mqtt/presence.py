"""Operator presence (DESIGN §5): who is alive, decided from retained heartbeats and last-wills.

An operator client publishes a retained heartbeat on
``roslink/operators/<user>/<client_id>`` about once a second; its last-will
is an empty retained message, which clears it. The tracker here is pure
logic so the bridge's safety decisions can be unit-tested without a broker.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from .protocol import Envelope, MessageId, RobotType, SystemStatus, encode

DEFAULT_OPERATOR_PERIOD = 1.0  # s between operator heartbeats


def operator_heartbeat(user: str, client_id: str, sequence_number: int = 0) -> bytes:
    """The payload an operator publishes (a ROSLink heartbeat naming the client)."""
    payload = {"type": int(RobotType.GENERIC), "name": client_id, "system_status": int(SystemStatus.ACTIVE),
               "owner_id": user, "mode": 0}
    return encode(Envelope(MessageId.HEARTBEAT, payload, 0, sequence_number))


@dataclass
class OperatorTracker:
    """Live operator clients, each with the time its last heartbeat arrived."""

    timeout: float
    _seen: dict[tuple[str, str], float] = field(default_factory=dict)

    def heartbeat(self, user: str, client_id: str, payload: bytes, now: float) -> bool:
        """Record one message on an operator topic; returns whether ``user`` is live afterwards.

        Any non-empty payload counts as a heartbeat (a Node-RED flow may send
        ``1``); an empty one is the last-will or a clean sign-off.
        """
        key = (user, client_id)
        if payload:
            self._seen[key] = now
        else:
            self._seen.pop(key, None)
        return self.is_live(user)

    def expire(self, now: float) -> list[str]:
        """Forget clients silent for longer than ``timeout``; return users who went away entirely."""
        stale = [key for key, at in self._seen.items() if now - at > self.timeout]
        users = {user for user, _ in stale}
        for key in stale:
            del self._seen[key]
        return sorted(u for u in users if not self.is_live(u))

    def is_live(self, user: str, client_id: str | None = None) -> bool:
        """Any client of ``user`` live, or that one client when ``client_id`` is given."""
        if client_id is not None:
            return (user, client_id) in self._seen
        return any(u == user for u, _ in self._seen)

    def live_users(self) -> set[str]:
        return {u for u, _ in self._seen}

    def clients(self) -> Iterable[tuple[str, str]]:
        return list(self._seen)
