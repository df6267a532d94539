"""Ports the ROS side makes by declaration: a module of this package lists in ``MAKES`` the ports it implements and
how each is made from :class:`RosSide`, and the bridge gathers them (:func:`made_ports`).

Why: an operation's port used to be one more attribute built in ``Bridge.__init__`` and one more argument handed to
the core, so a new operation touched the bridge's constructor. Declared here, it touches its own module only
(docs/architecture.md, "How to add an operation"). A port the bridge also drives itself (one whose users' holdings a
demotion withdraws, one the motion path calls) is made by the bridge and provided beside these (node.py ``_ports``).

A made port that has a ``supervise(now)`` method is called by the bridge's supervision tick (20 Hz, the executor's
thread): where a port expires what waited too long.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar, runtime_checkable

from ..core.capabilities.ports import PortKey, Ports

if TYPE_CHECKING:
    from rclpy.node import Node

    from ...config import Robot
    from ...topics import TopicTree
    from ..core.on_executor import OnExecutor
    from ..core.routes import Inbound
    from ..core.uplink_sender import Uplink

P = TypeVar("P")


@dataclass(frozen=True, slots=True)
class RosSide:
    """What a ROS port may be made from."""

    node: Node
    robot: Robot
    topics: TopicTree
    routes: Mapping[str, Inbound]  # the robot's MQTT→ROS rules by name
    uplink: Uplink  # where state and bulk leave
    publish_reliable: Callable[[str, bytes], None]  # the command link, QoS 1
    publish: Callable[[str, bytes, int], None]  # the command link, at the QoS given
    is_live: Callable[[str, str | None], bool]  # whether a user's (program's: its client id) presence is live
    on_executor: OnExecutor  # run a callable on the ROS executor's thread


@dataclass(frozen=True)  # no slots: typing sets __orig_class__ on an instance of PortMaker[X](…)
class PortMaker(Generic[P]):
    """One port a module makes: its key (declared beside the port in the core) and how it is made."""

    key: PortKey[P]
    make: Callable[[RosSide], P]


@runtime_checkable
class Supervised(Protocol):
    """A made port the bridge's supervision tick calls."""

    def supervise(self, now: float) -> None: ...


def declared_makers(package: str = __package__ or "") -> tuple[PortMaker[Any], ...]:
    """Every ``MAKES`` of the modules of ``package``, by module name (the same order at every start)."""
    found: list[PortMaker[Any]] = []
    for info in sorted(pkgutil.iter_modules(importlib.import_module(package).__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{package}.{info.name}")
        found += getattr(module, "MAKES", ())
    return tuple(found)


def made_ports(side: RosSide, ports: Ports, makers: Sequence[PortMaker[Any]] | None = None) -> list[object]:
    """Make every declared port (``makers``: these instead) and provide it in ``ports``; returns what was made."""
    made: list[object] = []
    for maker in declared_makers() if makers is None else makers:
        port = maker.make(side)
        ports.provide(maker.key, port)
        made.append(port)
    return made
