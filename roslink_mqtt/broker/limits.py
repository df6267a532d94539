"""What one login may cost the embedded broker, and the bookkeeping that enforces it.

Every number here bounds something an ordinary login -- a viewer included -- could
otherwise grow without limit or use to stall the event loop that carries every robot's
stop commands: packet sizes, subscriptions, retained bytes, messages queued for a client
that does not read, connections. Defaults suit the demo fleet and a few hundred robots;
robots.yaml ``broker.limits`` overrides them (docs/config.md, docs/safety.md).

Pure logic, no amqtt: :class:`RetainedQuota` is unit-tested alone and used by
:mod:`roslink_mqtt.broker.hardened`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

KIB, MIB = 1024, 1024 * 1024


@dataclass(frozen=True, slots=True)
class BrokerLimits:
    """Per-login and per-connection bounds of the embedded broker (0 = unlimited where noted)."""

    max_connect_bytes: int = 64 * KIB  # a CONNECT packet (its will payload included)
    max_subscribe_bytes: int = 64 * KIB  # a SUBSCRIBE or UNSUBSCRIBE packet
    max_subscriptions: int = 1024  # filters one session may hold
    max_connections_per_login: int = 32  # live connections of one login (0 = unlimited)
    # bytes of packets still arriving that one login's connections may hold together (0 = unlimited; never less
    # than one packet of broker.max_payload, so any packet the broker accepts fits)
    max_partial_bytes: int = 8 * MIB
    packet_piece_timeout: float = 60.0  # s within which each 64 KiB of a large packet must arrive (0 = no limit)
    max_queued_messages: int = 1000  # deliveries waiting for one slow client
    max_queued_bytes: int = 2 * MIB  # bytes waiting for one slow client (socket buffer included)
    slow_consumer_timeout: float = 30.0  # s a client may stay over the queue limit before it is dropped
    # bytes a client's connection may hold unacknowledged before robots' state to it is conflated, latest wins
    # per topic (hardened fix 26; 0 = never: first in, first out up to the limits above)
    conflate_backlog: int = 16 * KIB  # (raised to what the client's own rate carries in 0.25 s: far is not slow)
    max_conflated_topics: int = 1024  # state topics one backed-up client may have waiting (more: dropped)
    max_offline_messages: int = 1000  # QoS 1/2 messages kept for one disconnected persistent session
    retained_bytes_robot: int = 16 * MIB  # retained payload bytes one robot login may keep
    retained_bytes_user: int = 64 * KIB  # retained payload bytes one user login may keep (admins: total only)
    retained_bytes_total: int = 256 * MIB  # retained payload bytes in the whole broker
    max_presence_bytes: int = 4 * KIB  # payload of an operator presence heartbeat
    acl_cache_bytes: int = 256 * KIB  # topic bytes one session's ACL verdict cache may hold
    user_publish_rate: float = 100.0  # PUBLISH packets a second one user login may send, all its connections
    user_publish_burst: int = 200  # ... after a quiet spell (0 rate = unlimited); robots' logins are not paced

    @classmethod
    def from_mapping(cls, values: dict[str, Any]) -> BrokerLimits:
        """Build from name -> number (``--limit`` options); integer fields get integers."""
        out: dict[str, Any] = {}
        for f in fields(cls):
            if f.name in values:
                out[f.name] = float(values[f.name]) if f.type in ("float", float) else int(values[f.name])
        return cls(**out)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


class RetainedQuota:
    """Retained payload bytes per login and in total; a store over quota is refused, a clear always allowed."""

    __slots__ = ("limits", "_owner", "_size", "_per_login", "total")

    def __init__(self, limits: BrokerLimits) -> None:
        self.limits = limits
        self._owner: dict[str, str] = {}  # topic -> login that stored it
        self._size: dict[str, int] = {}  # topic -> payload bytes
        self._per_login: dict[str, int] = {}
        self.total = 0

    def used_by(self, login: str) -> int:
        return self._per_login.get(login, 0)

    def check(self, login: str, limit: int | None, topic: str, size: int) -> str | None:
        """None when ``login`` may retain ``size`` bytes on ``topic`` (replacing what is there), else why not.

        ``limit`` is the login's own quota (None = only the broker total applies).
        """
        old = self._size.get(topic, 0)
        old_mine = old if self._owner.get(topic) == login else 0
        if limit is not None and self.used_by(login) - old_mine + size > limit:
            return f"retained quota of {limit} bytes for this login is used up"
        if self.limits.retained_bytes_total and self.total - old + size > self.limits.retained_bytes_total:
            return f"broker-wide retained quota of {self.limits.retained_bytes_total} bytes is used up"
        return None

    def stored(self, login: str, topic: str, size: int) -> None:
        self.cleared(topic)
        self._owner[topic], self._size[topic] = login, size
        self._per_login[login] = self._per_login.get(login, 0) + size
        self.total += size

    def cleared(self, topic: str) -> None:
        size = self._size.pop(topic, None)
        if size is None:
            return
        login = self._owner.pop(topic)
        left = self._per_login[login] - size
        if left:
            self._per_login[login] = left
        else:
            del self._per_login[login]
        self.total -= size
