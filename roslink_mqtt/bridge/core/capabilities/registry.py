"""Every operation, built the same way: the ROS adapter hands the core its ports once (:class:`Ports`, by typed
key), and each capability builds itself from them (``build``, one signature for all). ROS-free.

Why: with each capability constructed by hand in the bridge, with a constructor shape of its own, adding an
operation meant editing the bridge's wiring too; with a list of operations and a dataclass of ports here, it meant
editing this module as well. Now a capability module declares what it serves (``SERVES``) and its port's key, and
this module gathers every module of the package: a new operation is its capability module and, when it needs ROS,
its port's module on the ROS side (docs/architecture.md, "How to add an operation").
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, cast

from .base import Capability, Report
from .ports import Ports

if TYPE_CHECKING:
    from ....config import Robot
    from ....topics import TopicTree
    from ..budget import RequestBudget
    from ..routes import Inbound


@dataclass(frozen=True, slots=True)
class Wiring:
    """Everything a capability may be built from."""

    robot: Robot
    topics: TopicTree
    routes: Mapping[str, Inbound]  # the robot's MQTT→ROS rules by name
    ports: Ports
    report: Report  # an error report on to/<user>/error (the endpoint's refuse)
    publish_reliable: Callable[[str, bytes], None]  # the command link, QoS 1
    publish: Callable[[str, bytes, int], None]  # the command link, at the QoS given
    budget: RequestBudget  # requests one user may have unanswered (calls and parameters together)


C = TypeVar("C", covariant=True)


class Operation(Protocol[C]):
    """A capability class: it builds itself from the wiring."""

    @classmethod
    def build(cls, wiring: Wiring) -> C: ...


def declared_operations(package: str = __package__ or "") -> tuple[Operation[Capability[Any]], ...]:
    """Every operation the modules of ``package`` declare in their ``SERVES``, by module name.

    Besides these, the endpoint serves ``cmd/*`` and ``control/*`` itself (the motion path and the control lease).
    The order is irrelevant (each has a verb of its own); sorted, it is the same at every start.
    """
    found: list[Operation[Capability[Any]]] = []
    for info in sorted(pkgutil.iter_modules(importlib.import_module(package).__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{package}.{info.name}")
        found += cast("Sequence[Operation[Capability[Any]]]", getattr(module, "SERVES", ()))
    return tuple(found)


OPERATIONS = declared_operations()


def build_all(wiring: Wiring, operations: Sequence[Operation[Capability[Any]]] = OPERATIONS) -> list[Capability[Any]]:
    """Every registered operation (``operations``: these instead), built from ``wiring``."""
    return [operation.build(wiring) for operation in operations]
