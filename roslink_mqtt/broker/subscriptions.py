"""The embedded broker's two routing tables -- subscriptions and retained messages -- as trees of topic levels.

amqtt 0.12 keeps both in flat dicts and matches every PUBLISH against every subscription filter (and every
SUBSCRIBE against every retained message), splitting both into levels each time: the cost of one message
grew with the whole fleet's subscriptions, and a fleet of 200 robots (about a thousand filters) spent more
time matching than the event loop has (bench/fleet.py, docs/scaling.md); a SUBSCRIBE of many filters against
thousands of retained messages held the loop for seconds. Here a lookup visits only the branches that can
match: a handful of dict look-ups whatever the fleet's size.

Each table is the broker's *only* copy: it is a ``MutableMapping`` with the shape of the dict amqtt expects
(``Broker._subscriptions``: filter -> list of (session, qos); ``Broker._retained_messages``: topic -> message),
so amqtt's own code reads and writes it, and nothing has to be kept in step with anything. Pure logic, no
amqtt.
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping
from typing import Any

from ..topics import filter_levels

_END = None  # key marking "an entry ends at this node"; holds (key, value)
Node = dict[Any, Any]


class _LevelTree(MutableMapping[str, Any]):
    """A mapping from topic strings (names or filters) to values, stored in a tree keyed by level."""

    __slots__ = ("_root", "_size")

    def __init__(self) -> None:
        self._root: Node = {}
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def _node(self, key: str) -> Node | None:
        node = self._root
        for level in filter_levels(key):
            child = node.get(level)
            if child is None:
                return None
            node = child
        return node

    def __contains__(self, key: object) -> bool:
        if not isinstance(key, str):
            return False
        node = self._node(key)
        return node is not None and _END in node

    def __getitem__(self, key: str) -> Any:
        node = self._node(key)
        if node is None or _END not in node:
            raise KeyError(key)
        return node[_END][1]

    def __setitem__(self, key: str, value: Any) -> None:
        node = self._root
        for level in filter_levels(key):
            node = node.setdefault(level, {})
        if _END not in node:
            self._size += 1
        node[_END] = (key, value)

    def __delitem__(self, key: str) -> None:
        path: list[tuple[Node, str]] = []
        node = self._root
        for level in filter_levels(key):
            child = node.get(level)
            if child is None:
                raise KeyError(key)
            path.append((node, level))
            node = child
        if node.pop(_END, None) is None:
            raise KeyError(key)
        self._size -= 1
        for parent, level in reversed(path):  # prune empty branches so memory follows the live entries
            if parent[level]:
                break
            del parent[level]

    def __iter__(self) -> Iterator[str]:
        """Every key, from a snapshot: the table may change while the caller awaits between items."""
        return iter([key for key, _value in self._entries(self._root, skip_dollar=False)])

    def clear(self) -> None:
        self._root, self._size = {}, 0

    @staticmethod
    def _entries(node: Node, *, skip_dollar: bool) -> Iterator[tuple[str, Any]]:
        """(key, value) of every entry at or below ``node``; iterative, so deep topics cannot exhaust the stack."""
        stack = [(node, skip_dollar)]
        while stack:
            current, top = stack.pop()
            for level, child in list(current.items()):
                if level is _END:
                    yield child
                elif not (top and level.startswith("$")):
                    stack.append((child, False))


class SubscriptionTable(_LevelTree):
    """filter -> subscribers (amqtt's list of (session, qos)); :meth:`matches` finds the filters a topic matches."""

    __slots__ = ()

    def matches(self, topic: str) -> list[tuple[str, Any]]:
        """(filter, subscribers) of every filter that ``topic`` (a topic name, no wildcards) matches.

        ``#`` matches the parent level too (``a/#`` matches ``a``); topics starting with ``$`` are not
        matched by a filter starting with a wildcard (MQTT-4.7.2-1).
        """
        parts = filter_levels(topic)
        found: list[tuple[str, Any]] = []
        dollar = topic.startswith("$")
        # iterative walk: (node, index of the next level to match)
        stack: list[tuple[Node, int]] = [(self._root, 0)]
        while stack:
            node, i = stack.pop()
            wild_ok = not (dollar and i == 0)
            if wild_ok:
                rest = node.get("#")
                if rest is not None and _END in rest:
                    found.append(rest[_END])
            if i == len(parts):
                if _END in node:
                    found.append(node[_END])
                continue
            exact = node.get(parts[i])
            if exact is not None:
                stack.append((exact, i + 1))
            if wild_ok:
                plus = node.get("+")
                if plus is not None:
                    stack.append((plus, i + 1))
        return found


class RetainedTable(_LevelTree):
    """topic -> retained message; :meth:`matches` finds the retained topics a filter matches."""

    __slots__ = ()

    def matches(self, topic_filter: str) -> Iterator[tuple[str, Any]]:
        """(topic, message) of every retained topic the filter matches (MQTT 3.1.1 §4.7; ``$`` topics are not
        matched by a filter starting with a wildcard)."""
        yield from self._walk(self._root, filter_levels(topic_filter), 0)

    def _walk(self, node: Node, levels: tuple[str, ...], i: int) -> Iterator[tuple[str, Any]]:
        if i == len(levels):
            entry = node.get(_END)
            if entry is not None:
                yield entry
            return
        level = levels[i]
        if level == "#":  # 'a/#' also matches 'a' itself (MQTT-4.7.1-2)
            yield from self._entries(node, skip_dollar=(i == 0))
            return
        if level == "+":
            for key, child in list(node.items()):
                if key is _END or (i == 0 and key.startswith("$")):
                    continue
                yield from self._walk(child, levels, i + 1)
            return
        child = node.get(level)
        if child is not None:
            yield from self._walk(child, levels, i + 1)
