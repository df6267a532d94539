"""``provide_action/<action>`` and ``action_update/<action>``: MQTT clients provide ROS actions. ROS-free.

A retained ``from/<user>/provide_action/<name>`` ``{"type": "pkg/action/T", …}`` offers an action (operators
only; an empty one withdraws it). The port (:class:`ActionProviderPort`, :mod:`roslink_mqtt.bridge.ros.action_provider`
with rclpy) runs the ROS action server while the provider is live, forwards goals and cancels as
``to/<user>/action_request/<name>`` and turns the provider's ``from/<user>/action_update/<name>`` into the goal's
acceptance, feedback and result (docs/protocol.md, "Actions provided by MQTT clients").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from ....protocol.provided_actions import ActionOffer, ActionUpdate
from ....topics import Verb
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring
from .offers import Offers


class ActionProviderPort(Protocol):
    def offer(self, user: str, name: str, offer: ActionOffer) -> str | None:
        """``user`` provides action ``name``; why not instead (an unknown type, another user provides it)."""
        ...

    def withdraw(self, user: str, name: str, reason: str) -> None:
        """``user`` no longer provides ``name``: its goals end with ``reason``."""
        ...

    def update(self, user: str, name: str, update: ActionUpdate, refused: Callable[[str], None]) -> None:
        """The provider's word on one of its goals; ``refused`` is called (later, any thread) with why, when there
        is no such goal or the update does not fit the action type."""
        ...


ACTION_PROVIDER_PORT = PortKey[ActionProviderPort]("action_provider", "actions MQTT clients provide to ROS")


class ProvideAction(Offers[ActionOffer]):
    verb = Verb.PROVIDE_ACTION

    @classmethod
    def build(cls, wiring: Wiring) -> ProvideAction:
        """From the bridge's wiring (capabilities/registry.py)."""
        port: ActionProviderPort = wiring.ports.get(ACTION_PROVIDER_PORT)
        return cls(wiring.robot.name, port, wiring.report)

    def read(self, name: str, payload: bytes) -> ActionOffer:
        return ActionOffer.from_json(payload)


class UpdateProvidedGoal:
    verb = Verb.ACTION_UPDATE

    @classmethod
    def build(cls, wiring: Wiring) -> UpdateProvidedGoal:
        """From the bridge's wiring (capabilities/registry.py)."""
        port: ActionProviderPort = wiring.ports.get(ACTION_PROVIDER_PORT)
        return cls(port, wiring.report)

    def __init__(self, port: ActionProviderPort, report: Report) -> None:
        self.port, self.report = port, report

    def parse(self, name: str, payload: bytes) -> ActionUpdate:
        return ActionUpdate.from_json(payload)

    def gate(self, request: Request[ActionUpdate], gates: Gates) -> Refusal | None:
        return None  # only the goal's own provider has it waiting (the port looks it up by user)

    def run(self, request: Request[ActionUpdate]) -> None:
        assert request.body is not None
        self.port.update(request.user, request.name, request.body,
                         lambda why: self.refuse(request, Refusal(why)))

    def refuse(self, request: Request[ActionUpdate], refusal: Refusal) -> None:
        body = request.body
        request_id, client_id = (body.id, body.client_id) if body is not None else \
            (refusal.request_id, refusal.client_id)
        self.report(request.user, request.topic, refusal.reason, client_id=client_id, request_id=request_id)


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (ProvideAction, UpdateProvidedGoal,)
