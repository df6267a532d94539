"""What MQTT clients offer the robot with a retained message: a service, an action, SDK node parameters. ROS-free.

The three verbs (``provide``, ``provide_action``, ``declare``) work alike: a retained body offers (operators only:
it puts something into the robot's ROS graph), an empty retained message withdraws (anyone may take back what they
offered), and the port decides whether the offer can stand (a type it cannot load, a name someone else holds).
"""

from __future__ import annotations

from typing import Generic, Protocol, TypeVar

from ....authorize import refusal
from ....topics import Verb
from .base import Gates, Refusal, Report, Request, Withdrawal


class Offer(Protocol):
    """A parsed offer body: it names the offering program (its presence client)."""

    @property
    def client_id(self) -> str | None: ...


OfferT = TypeVar("OfferT", bound=Offer)
OfferT_contra = TypeVar("OfferT_contra", bound=Offer, contravariant=True)


class OfferPort(Protocol[OfferT_contra]):
    def offer(self, user: str, name: str, offer: OfferT_contra) -> str | None:
        """``user`` offers ``name``; why it cannot stand instead."""
        ...

    def withdraw(self, user: str, name: str, reason: str) -> None:
        """``user`` takes ``name`` back; what waits on it fails with ``reason``."""
        ...


class Offers(Generic[OfferT]):
    """One offering verb: subclasses say which (``verb``) and how a body is read (:meth:`read`)."""

    verb: Verb

    def __init__(self, robot: str, port: OfferPort[OfferT], report: Report) -> None:
        self.robot, self.port, self.report = robot, port, report

    def read(self, name: str, payload: bytes) -> OfferT:
        """The offer in a non-empty body (raises ProtocolError)."""
        raise NotImplementedError

    def withdrawn(self, user: str, name: str) -> str:
        """Why what waits on a withdrawn offer fails."""
        return "withdrawn by the provider"

    def parse(self, name: str, payload: bytes) -> OfferT | Withdrawal:
        return self.read(name, payload) if payload else Withdrawal()

    def gate(self, request: Request[OfferT | Withdrawal], gates: Gates) -> Refusal | None:
        if isinstance(request.body, Withdrawal):
            return None  # anyone may take back what they offered
        why = refusal(request.user, request.role, self.verb, request.name, robot=self.robot)
        return Refusal(why) if why else None

    def run(self, request: Request[OfferT | Withdrawal]) -> None:
        body = request.body
        if isinstance(body, Withdrawal):
            self.port.withdraw(request.user, request.name, self.withdrawn(request.user, request.name))
        elif body is not None:
            why = self.port.offer(request.user, request.name, body)
            if why:
                self.refuse(request, Refusal(why))

    def refuse(self, request: Request[OfferT | Withdrawal], refusal: Refusal) -> None:
        body = request.body
        client_id = refusal.client_id if body is None or isinstance(body, Withdrawal) else body.client_id
        self.report(request.user, request.topic, refusal.reason, client_id=client_id)
