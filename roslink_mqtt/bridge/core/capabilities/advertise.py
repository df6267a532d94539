"""``advertise/<name>``: MQTT users keep the ROS publisher of an ``on_demand`` rule alive. ROS-free.

The legacy-ROSLink promise: ROS endpoints come and go with the programs behind them. A retained
``from/<user>/advertise/<name>`` ``{"type": "pkg/msg/T", "client_id": "<presence id>"}`` (the SDK's
``create_publisher``) advertises; an empty retained message withdraws (``destroy_publisher``), as does the
advertiser's presence ending. Publishing on the rule advertises implicitly. The port (:class:`AdvertisePort`,
:mod:`roslink_mqtt.bridge.ros.on_demand` with rclpy) creates and destroys the publishers to match.
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from typing import TYPE_CHECKING, Protocol

from ....authorize import refusal
from ....protocol.control import Advertisement
from ....topics import Verb
from .base import Gates, Refusal, Report, Request, Withdrawal
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring


class AdvertisePort(Protocol):
    def advertise(self, user: str, name: str, client_id: str | None) -> None:
        """``user`` publishes on ``name`` from ``client_id`` (None: from any of their live clients)."""
        ...

    def withdraw(self, user: str, name: str) -> None:
        """``user`` no longer advertises ``name``."""
        ...


ADVERTISE_PORT = PortKey[AdvertisePort]("advertise", "on-demand ROS publishers")


class Advertise:
    verb = Verb.ADVERTISE

    @classmethod
    def build(cls, wiring: Wiring) -> Advertise:
        """From the bridge's wiring (capabilities/registry.py)."""
        routes = wiring.routes
        on_demand = {name: route.rule.ros_type for name, route in routes.items() if route.rule.on_demand}
        return cls(wiring.robot.name, on_demand, {name for name in routes if name not in on_demand},
                   wiring.ports.get(ADVERTISE_PORT), wiring.report)

    def __init__(self, robot: str, on_demand: Mapping[str, str], always_there: Set[str], port: AdvertisePort,
                 report: Report) -> None:
        """``on_demand``: the on-demand rules' ROS types by MQTT name; ``always_there``: the other mqtt_to_ros
        names (advertising those is harmless and ignored)."""
        self.robot, self.on_demand, self.always_there, self.port, self.report = \
            robot, dict(on_demand), frozenset(always_there), port, report

    def parse(self, name: str, payload: bytes) -> Advertisement | Withdrawal:
        if not payload or (name not in self.on_demand and name in self.always_there):
            return Withdrawal()  # empty: withdrawn; a rule whose publisher always exists: nothing to read
        return Advertisement.from_json(payload)

    def gate(self, request: Request[Advertisement | Withdrawal], gates: Gates) -> Refusal | None:
        name, advert = request.name, request.body
        ros_type = self.on_demand.get(name)
        if ros_type is None:
            if name in self.always_there:
                return None  # its publisher always exists: nothing to do (run() ignores it)
            known = ", ".join(sorted({*self.on_demand, *self.always_there})) or "none"
            return Refusal(f"no mapping '{name}' on this robot (mqtt_to_ros rules: {known})")
        if isinstance(advert, Withdrawal):
            return None  # anyone may stop advertising
        why = refusal(request.user, request.role, Verb.ADVERTISE, name, robot=self.robot)
        if why:
            return Refusal(why)
        if advert is not None and advert.type != ros_type:
            return Refusal(f"'{name}' carries {ros_type}, not {advert.type}")
        return None

    def run(self, request: Request[Advertisement | Withdrawal]) -> None:
        if request.name not in self.on_demand:
            return
        if isinstance(request.body, Withdrawal):
            self.port.withdraw(request.user, request.name)
        elif request.body is not None:
            self.port.advertise(request.user, request.name, request.body.client_id)

    def refuse(self, request: Request[Advertisement | Withdrawal], refusal: Refusal) -> None:
        body = request.body
        client_id = body.client_id if isinstance(body, Advertisement) else refusal.client_id
        self.report(request.user, request.topic, refusal.reason, client_id=client_id)


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (Advertise,)
