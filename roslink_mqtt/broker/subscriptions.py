"""The subscription filters of the embedded broker in a tree of levels, so a PUBLISH visits only what can match.

amqtt 0.12 matches every PUBLISH against every subscription filter in the broker, splitting both into
levels each time: the cost of one message grows with the whole fleet's subscriptions, and a fleet of 200
robots (about a thousand filters) spent more time matching than the event loop has (bench/fleet.py,
docs/scaling.md). Here a topic of ``n`` levels visits at most ``n`` nodes per branch that can match: its
exact levels, ``+`` and ``#`` at each level -- a handful of dict look-ups whatever the fleet's size.

Pure logic, no amqtt. The broker keeps amqtt's own ``_subscriptions`` dict (filter -> subscribers) and
uses this index only to find which of its keys match; a filter whose subscribers are gone is dropped
lazily the next time it matches (:meth:`discard`), so the index never lists more than the broker had.
"""

from __future__ import annotations

from typing import Any

from ..topics import filter_levels

_END = None  # key marking "a filter ends at this node"; holds the filter string


class SubscriptionIndex:
    """Filters in a tree keyed by level; :meth:`matches` gives every filter a topic name matches (MQTT 3.1.1 §4.7)."""

    __slots__ = ("_root", "_size")

    def __init__(self) -> None:
        self._root: dict[Any, Any] = {}
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def __contains__(self, topic_filter: str) -> bool:
        node = self._root
        for level in filter_levels(topic_filter):
            child = node.get(level)
            if child is None:
                return False
            node = child
        return _END in node

    def add(self, topic_filter: str) -> None:
        node = self._root
        for level in filter_levels(topic_filter):
            node = node.setdefault(level, {})
        if _END not in node:
            node[_END] = topic_filter
            self._size += 1

    def discard(self, topic_filter: str) -> None:
        path: list[tuple[dict[Any, Any], str]] = []
        node = self._root
        for level in filter_levels(topic_filter):
            child = node.get(level)
            if child is None:
                return
            path.append((node, level))
            node = child
        if node.pop(_END, None) is None:
            return
        self._size -= 1
        for parent, level in reversed(path):  # prune empty branches so memory follows the live filters
            if parent[level]:
                break
            del parent[level]

    def matches(self, topic: str) -> list[str]:
        """Every stored filter that ``topic`` (a topic name, no wildcards) matches.

        ``#`` matches the parent level too (``a/#`` matches ``a``); topics starting with ``$`` are not
        matched by a filter starting with a wildcard (MQTT-4.7.2-1).
        """
        parts = filter_levels(topic)
        found: list[str] = []
        dollar = topic.startswith("$")
        # iterative walk: (node, index of the next level to match)
        stack: list[tuple[dict[Any, Any], int]] = [(self._root, 0)]
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
