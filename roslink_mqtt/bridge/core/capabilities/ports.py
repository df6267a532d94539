"""The ports the ROS adapter hands the core, by typed key. ROS-free.

Why keys instead of one field per port: with a field per port, every new operation's port was one more line in a
shared dataclass, and every test that built the ports had to name them all. Now a capability module declares its
port's key beside the port (``SERVICE_PORT = PortKey[ServicePort]("services", …)``), the ROS side provides an
implementation under that key, and the capability asks for it by the same key: the type checker sees
``ports.get(SERVICE_PORT)`` as a ``ServicePort``, and no third file names the port.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, TypeVar, cast

P = TypeVar("P")


@dataclass(frozen=True, eq=False)  # no slots: typing sets __orig_class__ on an instance of PortKey[X](…)
class PortKey(Generic[P]):
    """The name of one port, typed by what implements it. Compared by identity: one key per port."""

    name: str
    meaning: str  # what the ROS side carries out through it (the error of a missing port says so)

    def __repr__(self) -> str:
        return f"PortKey({self.name!r})"


class MissingPort(LookupError):
    """A capability asked for a port the ROS side did not provide."""


class Ports:
    """What the ROS adapter (bridge/ros/) implements for the core's operations, one implementation per key."""

    def __init__(self) -> None:
        self._given: dict[PortKey[Any], object] = {}

    def provide(self, key: PortKey[P], port: P) -> Ports:
        """Hand over ``port`` under ``key`` (once per key); returns self, so provisions chain."""
        if key in self._given:
            raise ValueError(f"port '{key.name}' is provided twice")
        self._given[key] = port
        return self

    def get(self, key: PortKey[P]) -> P:
        """The implementation of ``key``; :class:`MissingPort` when the ROS side gave none."""
        try:
            return cast("P", self._given[key])
        except KeyError:
            raise MissingPort(f"no port '{key.name}' ({key.meaning}): the ROS side provides none") from None

    def optional(self, key: PortKey[P]) -> P | None:
        """The implementation of ``key``, or None where the robot has none (a ring buffer it does not keep)."""
        return cast("P | None", self._given.get(key))

    def __contains__(self, key: PortKey[Any]) -> bool:
        return key in self._given

    @property
    def names(self) -> list[str]:
        """The keys provided, by name (for a log line and the tests)."""
        return sorted(key.name for key in self._given)
