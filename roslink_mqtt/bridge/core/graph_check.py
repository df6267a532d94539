"""Is anyone on the other end? Rules whose ROS topic has no publisher, or whose ROS service has no server. ROS-free.

A typo in a rule's ROS name (``ros_topic: odm``) is no error the bridge can see at start: ROS creates the
subscription all the same, and the state stream just never sends anything. So a few seconds after it starts
(:data:`GRAPH_CHECK_DELAY`: discovery and the robot's own nodes take a moment), and every
:data:`GRAPH_CHECK_PERIOD` after that, the bridge looks at the ROS graph (bridge/ros/node.py asks rclpy) and, for every
ROS→MQTT rule whose topic has no publisher and every ROS service it calls that has no server, logs a warning with
the closest name that does exist, and marks the entry in its retained description (``warning``), so ``echo`` and
``info`` can say what is true. A publisher that appears later clears the mark.

The decisions are here, as pure functions of what the graph holds, so they are unit-tested without ROS.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

GRAPH_CHECK_DELAY = 4.0  # s after the bridge starts: the first look at the ROS graph
GRAPH_CHECK_PERIOD = 5.0  # s between looks after that (a mark clears once the publisher or server appears)
TOPIC, SERVICE = "topic", "service"
CLOSE_CUTOFF = 0.6  # difflib ratio: "/odm" → "/odom", "/resett" → "/reset"


@dataclass(frozen=True, slots=True)
class Expected:
    """One ROS name a rule needs someone on the other end of."""

    entry: str  # what users know it by: the leaf (state/global_motion, cmd/land, call/reset)
    kind: str  # TOPIC (needs a publisher) or SERVICE (needs a server)
    name: str  # the resolved ROS name (namespace and remapping applied)
    ros_type: str


def closest(name: str, ros_type: str, existing: Iterable[tuple[str, Iterable[str]]]) -> str | None:
    """The existing name most like ``name``: of the same type if one is close enough, else of any type."""
    others = [(n, tuple(types)) for n, types in existing if n != name]
    for pool in ([n for n, types in others if ros_type in types], [n for n, _ in others]):
        match = difflib.get_close_matches(name, pool, n=1, cutoff=CLOSE_CUTOFF)
        if match:
            return match[0]
    return None


def missing_peer(expected: Expected, existing: Iterable[tuple[str, Iterable[str]]]) -> str:
    """The warning for a name nobody serves, to follow "the rule for <entry> ": what it uses, that nobody is there,
    and the closest name that is (``reads ROS topic /odm, which has no publisher (did you mean /odom?)``)."""
    uses, peer = ("reads", "publisher") if expected.kind == TOPIC else ("calls", "server")
    near = closest(expected.name, expected.ros_type, existing)
    hint = f" (did you mean {near}?)" if near else ""
    return f"{uses} ROS {expected.kind} {expected.name}, which has no {peer}{hint}"


def check(expected: Iterable[Expected], has_peer: Callable[[Expected], bool],
          existing: Callable[[str], list[tuple[str, list[str]]]]) -> dict[str, str]:
    """entry → warning, for every expected name without a publisher (topics) or server (services).

    ``existing(kind)`` lists the names of that kind that do have one, with their types; it is asked only when
    something is missing (and once per kind)."""
    found: dict[str, str] = {}
    listed: dict[str, list[tuple[str, list[str]]]] = {}
    for e in expected:
        if has_peer(e):
            continue
        if e.kind not in listed:
            listed[e.kind] = existing(e.kind)
        found[e.entry] = missing_peer(e, listed[e.kind])
    return found


def changes(before: Mapping[str, str], after: Mapping[str, str]) -> tuple[dict[str, str], list[str]]:
    """(entries newly warned about or with another warning, entries whose warning cleared)."""
    new = {entry: text for entry, text in after.items() if before.get(entry) != text}
    return new, sorted(set(before) - set(after))
