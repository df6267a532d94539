"""``provide/<service>`` and ``response/<service>``: MQTT clients provide ROS services. ROS-free.

A retained ``from/<user>/provide/<name>`` ``{"type": "pkg/srv/T", "timeout": s, "client_id": …}`` offers a
service (operators only); an empty one withdraws it. The port (:class:`ProviderPort`,
:mod:`roslink_mqtt.bridge.ros.service_provider` with rclpy) creates the ROS service while the provider is live,
forwards each ROS call as ``to/<provider>/request/<name>`` and answers it with the provider's
``from/<provider>/response/<name>``. Refusals go on the provider's error topic.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from ....protocol.control import ProviderResponse, ServiceOffer
from ....topics import Verb
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring
from .offers import Offers


class ProviderPort(Protocol):
    def offer(self, user: str, name: str, offer: ServiceOffer) -> str | None:
        """``user`` provides service ``name``; why not instead (an unknown type, another user provides it)."""
        ...

    def withdraw(self, user: str, name: str, reason: str) -> None:
        """``user`` no longer provides ``name``: waiting ROS calls fail with ``reason``."""
        ...

    def respond(self, user: str, name: str, answer: ProviderResponse) -> str | None:
        """The provider's answer to a forwarded call; why not instead (no such call waiting)."""
        ...


PROVIDER_PORT = PortKey[ProviderPort]("provider", "services MQTT clients provide to ROS")


class ProvideService(Offers[ServiceOffer]):
    verb = Verb.PROVIDE

    @classmethod
    def build(cls, wiring: Wiring) -> ProvideService:
        """From the bridge's wiring (capabilities/registry.py)."""
        port: ProviderPort = wiring.ports.get(PROVIDER_PORT)
        return cls(wiring.robot.name, port, wiring.report)

    def read(self, name: str, payload: bytes) -> ServiceOffer:
        return ServiceOffer.from_json(payload)


class RespondToCall:
    verb = Verb.RESPONSE

    @classmethod
    def build(cls, wiring: Wiring) -> RespondToCall:
        """From the bridge's wiring (capabilities/registry.py)."""
        port: ProviderPort = wiring.ports.get(PROVIDER_PORT)
        return cls(port, wiring.report)

    def __init__(self, port: ProviderPort, report: Report) -> None:
        self.port, self.report = port, report

    def parse(self, name: str, payload: bytes) -> ProviderResponse:
        return ProviderResponse.from_json(payload)

    def gate(self, request: Request[ProviderResponse], gates: Gates) -> Refusal | None:
        return None  # only the call's own provider has it waiting (the port looks it up by user)

    def run(self, request: Request[ProviderResponse]) -> None:
        assert request.body is not None
        why = self.port.respond(request.user, request.name, request.body)
        if why:
            self.refuse(request, Refusal(why))

    def refuse(self, request: Request[ProviderResponse], refusal: Refusal) -> None:
        body = request.body
        self.report(request.user, request.topic, refusal.reason,
                    client_id=body.client_id if body is not None else refusal.client_id)


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (ProvideService, RespondToCall,)
