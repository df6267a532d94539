"""What one login may cost the embedded broker, and the bookkeeping that enforces it.

Every number here bounds something an ordinary login -- a viewer included -- could
otherwise grow without limit or use to stall the event loop that carries every robot's
stop commands: packet sizes, subscriptions, retained bytes, messages queued for a client
that does not read, connections. Defaults suit the demo fleet and a few hundred robots;
robots.yaml ``broker.limits`` overrides them (docs/config.md, docs/safety.md).

Pure logic, no amqtt: :class:`RetainedIndex` and :class:`RetainedQuota` are unit-tested
alone and used by :mod:`roslink_mqtt.broker.hardened`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, fields
from typing import Any

from ..topics import filter_levels

KIB, MIB = 1024, 1024 * 1024


@dataclass(frozen=True, slots=True)
class BrokerLimits:
    """Per-login and per-connection bounds of the embedded broker (0 = unlimited where noted)."""

    max_connect_bytes: int = 64 * KIB  # a CONNECT packet (its will payload included)
    max_subscribe_bytes: int = 64 * KIB  # a SUBSCRIBE or UNSUBSCRIBE packet
    max_subscriptions: int = 1024  # filters one session may hold
    max_connections_per_login: int = 32  # live connections of one login (0 = unlimited)
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


def split_topic(topic: str) -> tuple[str, ...]:
    return filter_levels(topic)


class RetainedIndex:
    """Retained topics in a tree of levels, so a SUBSCRIBE visits only the branches its filter can match.

    amqtt keeps retained messages in one dict and matches every filter against every
    entry; with thousands of retained messages a SUBSCRIBE of many filters then held the
    event loop for seconds. Here a filter without wildcards is one walk down the tree, and
    ``+``/``#`` visit only what lies below the levels they name.
    """

    __slots__ = ("_root", "_size")

    def __init__(self) -> None:
        self._root: dict[str | None, Any] = {}  # level → child node; None → the retained topic ending here
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def add(self, topic: str) -> None:
        node = self._root
        for level in split_topic(topic):
            node = node.setdefault(level, {})
        if None not in node:
            node[None] = topic  # the key None marks "a retained message ends here"
            self._size += 1

    def discard(self, topic: str) -> None:
        path: list[tuple[dict[str | None, Any], str]] = []
        node = self._root
        for level in split_topic(topic):
            child = node.get(level)
            if child is None:
                return
            path.append((node, level))
            node = child
        if node.pop(None, None) is None:
            return
        self._size -= 1
        for parent, level in reversed(path):  # prune empty branches so memory follows the live set
            if parent[level]:
                break
            del parent[level]

    def matches(self, topic_filter: str) -> Iterator[str]:
        """Every retained topic the filter matches (MQTT 3.1.1 §4.7, ``$`` topics excluded from wildcards)."""
        levels = split_topic(topic_filter)
        yield from self._walk(self._root, levels, 0)

    def _walk(self, node: dict[str | None, Any], levels: tuple[str, ...], i: int) -> Iterator[str]:
        if i == len(levels):
            topic = node.get(None)
            if topic is not None:
                yield topic
            return
        level = levels[i]
        if level == "#":
            yield from self._subtree(node, skip_dollar=(i == 0))
            return
        if level == "+":
            for key, child in list(node.items()):
                if key is None or (i == 0 and key.startswith("$")):
                    continue
                yield from self._walk(child, levels, i + 1)
            return
        child = node.get(level)
        if child is not None:
            yield from self._walk(child, levels, i + 1)

    def _subtree(self, node: dict[str | None, Any], *, skip_dollar: bool) -> Iterator[str]:
        # 'a/#' also matches 'a' itself (MQTT-4.7.1-2); iterative, so deep topics cannot exhaust the stack
        stack = [(node, skip_dollar)]
        while stack:
            current, top = stack.pop()
            for key, child in list(current.items()):
                if key is None:
                    yield child
                elif not (top and key.startswith("$")):
                    stack.append((child, False))


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
