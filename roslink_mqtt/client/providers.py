"""Services this program provides to ROS through a robot's bridge.

An offer is a *retained* ``from/<user>/provide/<service>`` naming the ROS type
and our presence client id: the bridge creates the ROS service while that
client's heartbeat is live, so if this process dies its last-will removes the
ROS side without anyone withdrawing. Offers are re-published on every
reconnect, because a broker that restarted without persistence has forgotten
them. Requests arrive on the network thread and are handed to a
:class:`~roslink_mqtt.client.dispatch.CallbackQueue`: a handler may take
seconds, and the network thread must keep delivering meanwhile.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from ..protocol import ProtocolError
from ..protocol.control import ProviderRequest, ProviderResponse, ServiceOffer
from ..ros_names import is_interface
from ..topics import TopicTree, check_path
from .connection import Connection
from .dispatch import CallbackQueue
from .errors import InvalidArgument, InvalidType, RobotError

log = logging.getLogger("roslink_mqtt.client")

Handler = Callable[[dict[str, Any]], dict[str, Any]]  # request args -> response values; raise to fail


class ProvidedService:
    """One offered service; :meth:`withdraw` removes it (and the ROS side)."""

    def __init__(self, owner: ServiceProviders, robot: str, name: str, srv_type: str, timeout: float,
                 handler: Handler, callbacks: CallbackQueue) -> None:
        self._owner = owner
        self.robot, self.name, self.srv_type, self.timeout = robot, name, srv_type, timeout
        self.handler, self.callbacks = handler, callbacks
        self.refused: str | None = None  # set when the robot refuses the offer (e.g. not an operator)
        self.calls = 0  # requests answered

    @property
    def active(self) -> bool:
        return self._owner.get(self.robot, self.name) is self

    def withdraw(self) -> None:
        self._owner.withdraw(self)

    def __repr__(self) -> str:
        return f"<ProvidedService {self.robot}/{self.name} ({self.srv_type})>"


class ServiceProviders:
    """The offers of one connection."""

    def __init__(self, connection: Connection, topics: TopicTree, user: str) -> None:
        self.connection, self.topics, self.user = connection, topics, user
        self._lock = threading.Lock()
        self._offers: dict[tuple[str, str], ProvidedService] = {}
        connection.on_connected.append(self._republish)

    def provide(self, robot: str, name: str, srv_type: str, handler: Handler, callbacks: CallbackQueue,
                timeout: float = 5.0, *, refused: str | None = None) -> ProvidedService:
        """Offer ``name`` (type ``pkg/srv/Type``) on ``robot``; requests run ``handler`` via ``callbacks``.

        ``refused``: we already know the robot will not have it (the broker would drop the offer):
        the returned offer says why and nothing is published.
        """
        check_path(name, "service")
        if not isinstance(srv_type, str) or not is_interface(srv_type, "srv"):
            raise InvalidArgument(f"service type must look like 'std_srvs/srv/Trigger', got {srv_type!r}")
        if not 0 < timeout <= 3600:
            raise InvalidArgument("timeout must be in (0, 3600] seconds")
        if self.connection.presence is None:
            raise InvalidArgument("providing a service needs operator presence: the robot keeps the ROS service only "
                             "while our presence heartbeat is live (create the client with presence=True)")
        offer = ProvidedService(self, robot, name, srv_type, float(timeout), handler, callbacks)
        if refused is not None:
            offer.refused = refused
            return offer
        with self._lock:
            if (robot, name) in self._offers:
                raise InvalidArgument(f"already providing '{name}' on {robot}")
            self._offers[(robot, name)] = offer
        self._publish_offer(offer)
        return offer

    def get(self, robot: str, name: str) -> ProvidedService | None:
        with self._lock:
            return self._offers.get((robot, name))

    def withdraw(self, offer: ProvidedService, wait: float = 2.0) -> None:
        """Withdraw: an empty retained message on the provide topic; the bridge removes the ROS service."""
        with self._lock:
            if self._offers.get((offer.robot, offer.name)) is not offer:
                return
            del self._offers[(offer.robot, offer.name)]
        info = self.connection.publish(self.topics.provide(offer.robot, self.user, offer.name), b"",
                                       qos=ServiceOffer.QOS, retain=ServiceOffer.RETAINED)
        if wait and not self.connection.on_network_thread() and self.connection.connected.is_set():
            try:
                info.wait_for_publish(wait)
            except (RuntimeError, ValueError):
                pass  # the connection went meanwhile: the broker's copy goes with the session (or our will)

    def withdraw_all(self) -> None:
        with self._lock:
            offers = list(self._offers.values())
        for offer in offers:
            self.withdraw(offer)

    def _publish_offer(self, offer: ProvidedService) -> None:
        body = ServiceOffer(offer.srv_type, offer.timeout, self.connection.client_id)
        self.connection.publish(self.topics.provide(offer.robot, self.user, offer.name), body.to_json(),
                                qos=ServiceOffer.QOS, retain=ServiceOffer.RETAINED)

    def _republish(self) -> None:
        with self._lock:
            offers = list(self._offers.values())
        for offer in offers:
            self._publish_offer(offer)

    # -- network thread ------------------------------------------------------------------
    def on_request(self, robot: str, name: str, payload: bytes) -> None:
        """``to/<user>/request/<name>``: queue the handler; answer errors at once."""
        try:
            request = ProviderRequest.from_json(payload)
        except ProtocolError as err:
            log.warning("malformed request for %s on %s: %s", name, robot, err)
            return
        call_id, args, target = request.id, request.args, request.client_id
        offer = self.get(robot, name)
        if target is not None and target != self.connection.client_id:
            return  # the robot names another of this user's clients as the provider
        if offer is None:
            # Every client of this user sees the user's requests; another one of them may provide it.
            log.debug("ignoring request for %s on %s: not provided by this client", name, robot)
            return
        offer.callbacks.put(lambda: self._serve(offer, call_id, args))

    def on_error(self, error: RobotError) -> bool:
        """An error report about one of our offers (True if it was): remember why it was refused."""
        with self._lock:
            for offer in self._offers.values():
                if error.topic == self.topics.provide(offer.robot, self.user, offer.name):
                    offer.refused = error.error
                    return True
        return False

    def refuse_robot(self, robot: str, reason: str) -> list[ProvidedService]:
        """Mark every offer on ``robot`` refused (we are no operator there: the broker drops our offers)."""
        with self._lock:
            offers = [o for o in self._offers.values() if o.robot == robot and o.refused is None]
            for offer in offers:
                offer.refused = reason
        return offers

    # -- the handler (dispatcher thread) ---------------------------------------------------
    def _serve(self, offer: ProvidedService, call_id: Any, args: dict[str, Any]) -> None:
        try:
            values = offer.handler(args)
            if not isinstance(values, dict):
                raise InvalidType(f"the handler returned {type(values).__name__}, expected a dict of response fields")
            payload = ProviderResponse(call_id, True, values, client_id=self.connection.client_id).to_json()
        except Exception as err:  # the ROS caller gets the reason instead of waiting for the timeout
            log.exception("service %s on %s failed", offer.name, offer.robot)
            self._respond(offer.robot, offer.name, call_id, error=f"{type(err).__name__}: {err}")
            return
        offer.calls += 1
        self.connection.publish(self.topics.response(offer.robot, self.user, offer.name), payload,
                                qos=ProviderResponse.QOS)

    def _respond(self, robot: str, name: str, call_id: Any, *, error: str) -> None:
        self.connection.publish(self.topics.response(robot, self.user, name),
                                ProviderResponse(call_id, False, error=error,
                                                 client_id=self.connection.client_id).to_json(),
                                qos=ProviderResponse.QOS)
