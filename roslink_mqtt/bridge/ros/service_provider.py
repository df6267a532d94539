"""Services provided by MQTT clients to ROS, with rclpy: the port of the provide and response capabilities.

Who may provide is :mod:`roslink_mqtt.bridge.core.capabilities.provide`'s (ROS-free). Here: the bridge creates the
ROS service while the provider is live, forwards each call as ``to/<provider>/request/<name>`` and answers with
the provider's ``from/<provider>/response/<name>``. When the provider withdraws or goes away, the ROS service is
destroyed and waiting ROS calls fail cleanly (docs/protocol.md, "Services provided by MQTT clients"). The other
direction, MQTT users calling ROS services, is :mod:`.service_caller`.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_services_default
from rclpy.service import Service

from ...config import Robot
from ...protocol.control import ProviderRequest, ProviderResponse, ServiceOffer
from ...topics import TopicTree
from ..core.on_executor import OnExecutor
from ..core.ros_types import UnknownTypeError, load_interface
from .convert import ConversionError, converter_for

log = logging.getLogger("roslink_mqtt.bridge.services")

Publish = Callable[[str, bytes], None]


@dataclass(eq=False)
class _Waiting:
    """A ROS call to a provided service, parked until the provider answers or time runs out.

    Answered once both halves are here: the ``outcome`` (the provider's reply from the MQTT thread, or a failure
    from the timeout or the provider leaving) and the ROS ``header`` to answer (from the executor, right after the
    service callback returned this very object). Whichever arrives second sends the response.
    """

    offer: Any  # the _Provided it belongs to
    deadline: float
    response: Any  # the service type's empty response, filled in from the outcome
    outcome: tuple[str, Any] | None = None  # ("ok", ProviderResponse) or ("error", reason)
    header: Any = None
    sent: bool = False


@dataclass
class _Provided:
    user: str
    name: str
    srv: Any
    timeout: float
    client_id: str | None = None  # the provider's presence id: the service lives while that client does
    service: Any = None  # the rclpy Service while it exists (created/destroyed by refresh only)
    waiting: dict[str, _Waiting] = field(default_factory=dict)
    ending: tuple[float, str] | None = None  # (since, why): failing calls, destroyed once they have answered


class ProvidedServices:
    """ROS services whose implementation lives in an MQTT client.

    MQTT messages only edit the table of offers; :meth:`refresh`, run by the
    executor, creates and destroys the rclpy services to match, so ROS
    entities are never touched from paho's thread. A ROS call's callback
    publishes the request and returns at once; the response goes out later,
    when the provider's reply (MQTT thread) or the call's deadline (supervision
    timer) arrives (:class:`_Waiting`). A waiting call holds no thread and no
    coroutine, so either executor can run the bridge (the EventsExecutor has
    no asynchronous service callbacks) and a slow provider can never starve
    the failsafe checks.

    Every ROS caller gets an answer: ``max_concurrent`` bounds how many calls
    may wait at once (all services together), and a call beyond it is
    answered at once with a failure rather than queued. ``queue_depth`` is
    the ROS QoS depth of each service: ROS keeps only that many requests the
    executor has not taken yet and drops older ones *silently* (their callers
    would wait forever), so it must cover a burst; ROS's default is 10.
    """

    def __init__(self, node: Node, robot: Robot, topics: TopicTree, publish: Publish,
                 is_live: Callable[[str, str | None], bool], on_executor: OnExecutor, max_concurrent: int = 64,
                 queue_depth: int = 100) -> None:
        self.node, self.robot, self.topics, self.publish = node, robot, topics, publish
        self.on_executor, self.is_live = on_executor, is_live
        self.group = ReentrantCallbackGroup()
        self._lock = threading.RLock()
        self.max_concurrent = max_concurrent
        self.qos = QoSProfile(history=qos_profile_services_default.history, depth=queue_depth,
                              reliability=qos_profile_services_default.reliability,
                              durability=qos_profile_services_default.durability)
        self._refusing = False  # calls are being refused for overload (logged once per episode, not per call)
        self.offers: dict[tuple[str, str], _Provided] = {}  # (user, name) -> offer
        self._retired: list[_Provided] = []  # withdrawn offers whose ROS service still exists
        self._ids = itertools.count(1)

    # -- provider side (MQTT thread) ------------------------------------------------
    def offer(self, user: str, name: str, offer: ServiceOffer) -> str | None:
        """``user`` provides ``name`` (ProviderPort; the capability checked the grant). Why not, or None.

        ``offer.client_id`` names the provider's operator-presence client: the ROS service exists while that
        client is live (else while any client of the user is), so the provider's death removes it even if the
        same user is logged in elsewhere.
        """
        try:
            srv = load_interface(offer.type)
        except UnknownTypeError as err:
            return str(err)
        with self._lock:
            taken = [u for (u, n), o in self.offers.items() if n == name and u != user]
            if taken:
                return f"service '{name}' is already provided by {taken[0]}"
            old = self.offers.get((user, name))
            if old is not None and old.srv is srv:
                old.timeout, old.client_id = float(offer.timeout), offer.client_id
                return None  # the same offer again (e.g. retained redelivery after a reconnect)
            if old is not None:
                self._retire(old, "re-offered with another type")
            self.offers[(user, name)] = _Provided(user, name, srv, float(offer.timeout), offer.client_id)
        return None

    def withdraw(self, user: str, name: str, reason: str) -> None:
        with self._lock:
            offer = self.offers.pop((user, name), None)
            if offer is not None:
                self._retire(offer, reason)

    def withdraw_user(self, user: str, reason: str) -> None:
        """Withdraw every service ``user`` provides (e.g. their operator grant was removed)."""
        with self._lock:
            for key in [k for k in self.offers if k[0] == user]:
                self._retire(self.offers.pop(key), reason)

    def _retire(self, offer: _Provided, reason: str) -> None:
        self._end(offer, reason)
        self._retired.append(offer)

    def _end(self, offer: _Provided, reason: str) -> None:
        """Fail every waiting call now; the service itself goes once those replies are out."""
        with self._lock:
            if offer.ending is None:
                offer.ending = (time.monotonic(), reason)
            calls = [offer.waiting.pop(call_id) for call_id in list(offer.waiting)]
        for call in calls:
            self._resolve(call, ("error", reason))

    def _resolve(self, call: _Waiting, outcome: tuple[str, Any]) -> None:
        """Hand a parked call its outcome (any thread; the caller has removed it from ``waiting``)."""
        with self._lock:
            if call.outcome is not None:
                return
            call.outcome = outcome
            ready = call.header is not None
        if ready:
            self.on_executor.run(lambda: self._send(call))

    def _park_header(self, call: _Waiting, header: Any) -> None:
        """The executor hands over the ROS header to answer (right after the callback returned ``call``)."""
        with self._lock:
            call.header = header
            ready = call.outcome is not None
        if ready:
            self._send(call)

    def _send(self, call: _Waiting) -> None:
        """Answer the ROS caller from the outcome (executor thread, exactly once)."""
        with self._lock:
            if call.sent:
                return
            call.sent = True
        service = call.offer.service
        if service is None:
            return  # destroyed meanwhile: its callers see the service vanish
        try:
            _SEND_RESPONSE(service, self._response_for(call), call.header)
        except InvalidHandle:
            pass  # destroyed meanwhile

    def expire(self, now: float) -> None:
        """Fail calls whose provider did not answer in time (called from the supervision timer)."""
        with self._lock:
            late = [(offer, call_id) for offer in [*self.offers.values(), *self._retired]
                    for call_id, call in offer.waiting.items() if now > call.deadline]
            calls = [(offer, offer.waiting.pop(call_id)) for offer, call_id in late]
        for offer, call in calls:
            self._resolve(call, ("error", f"provider {offer.user} did not answer within {offer.timeout:g} s"))

    # -- reconcile (executor thread) -------------------------------------------------------
    def refresh(self) -> None:
        """Create services whose provider is live; destroy withdrawn ones and those whose provider left."""
        with self._lock:
            self._retired = [offer for offer in self._retired if not self._destroy_when_done(offer)]
            for offer in self.offers.values():
                live = self.is_live(offer.user, offer.client_id)
                if live and offer.service is None:
                    offer.ending = None
                    offer.service = self._create_service(offer)
                    log.info("providing ROS service %s for %s", offer.service.srv_name, offer.user)
                elif live and offer.ending is not None:
                    offer.ending = None  # the provider came back before its service was removed
                elif not live and offer.service is not None:
                    self._end(offer, f"provider {offer.user} went away")
                    self._destroy_when_done(offer)

    def _destroy_when_done(self, offer: _Provided, grace: float = 0.3) -> bool:
        """Destroy the service once no call waits and the last reply had time to go out."""
        if offer.service is not None:
            if offer.waiting or offer.ending is None or time.monotonic() - offer.ending[0] < grace:
                return False
            self.node.destroy_service(offer.service)
            offer.service = None
            log.info("removed ROS service %s: %s", offer.name, offer.ending[1])
        return True

    def respond(self, user: str, name: str, answer: ProviderResponse) -> str | None:
        """``from/<provider>/response/<name>``: wake the ROS call waiting for it (ProviderPort). Why not, or None."""
        with self._lock:
            offer = self.offers.get((user, name))
            call = offer.waiting.pop(answer.id, None) if offer is not None and isinstance(answer.id, str) else None
        if call is None:
            return f"no pending request with id {answer.id!r} for '{name}'"
        self._resolve(call, ("ok", answer))
        return None

    # -- ROS side (executor thread) --------------------------------------------------------
    def _create_service(self, offer: _Provided) -> Any:
        """The rclpy service for ``offer``, its ``send_response`` taught to park deferred answers.

        Both executors answer a call with ``service.send_response(callback(request, response), header)``. Our
        callback returns a :class:`_Waiting` when the answer comes later; the instance's ``send_response`` then
        keeps the header with it instead of sending, and :meth:`_send` sends the real response once it is known.
        """
        service = self.node.create_service(offer.srv, offer.name,
                                           lambda request, response: self._serve(offer, request, response),
                                           qos_profile=self.qos, callback_group=self.group)

        def send_response(response: Any, header: Any) -> None:
            if isinstance(response, _Waiting):
                self._park_header(response, header)
            else:
                _SEND_RESPONSE(service, response, header)

        # an instance attribute over rclpy's method, on purpose: the executors call service.send_response
        service.send_response = send_response  # type: ignore[method-assign]
        return service

    def _response_for(self, call: _Waiting) -> Any:
        reply: Any  # a ProviderResponse when status is "ok", else the reason (str)
        status, reply = call.outcome if call.outcome is not None else ("error", "no outcome")
        response = call.response
        if status == "error":
            return _failed(response, reply)
        if not reply.result:
            return _failed(response, reply.failure)
        try:
            return converter_for(type(response)).from_dict(reply.values or {})
        except ConversionError as err:
            return _failed(response, f"provider sent a bad response: {err}")

    def _serve(self, offer: _Provided, request: Any, response: Any) -> Any:
        with self._lock:
            if offer.ending is not None:
                return _failed(response, offer.ending[1])
            if sum(len(o.waiting) for o in self.offers.values()) >= self.max_concurrent:
                if not self._refusing:
                    self._refusing = True
                    log.warning("refusing calls to provided services on %s: %d already wait for their providers "
                                "(bridge.provided_max_calls)", self.robot.name, self.max_concurrent)
                return _failed(response, f"too many concurrent calls to provided services on {self.robot.name} "
                                         f"(limit {self.max_concurrent})", quiet=True)
            self._refusing = False
            call_id = f"{self.robot.name}-{next(self._ids)}"
            call = offer.waiting[call_id] = _Waiting(offer, time.monotonic() + offer.timeout, response)
        # client_id: several clients of one user may listen; it names the provider
        body = ProviderRequest(call_id, converter_for(type(request)).to_dict(request), offer.client_id)
        self.publish(self.topics.request(self.robot.name, offer.user, offer.name), body.to_json())
        return call  # answered by _send once the reply (or the timeout) and the header are both here


_SEND_RESPONSE = Service.send_response  # the class's own, which the instances' deferring wrapper calls


def _failed(response: Any, reason: str, *, quiet: bool = False) -> Any:
    """A response that says it failed, where the type can say so (success/message fields).

    A type without such fields still gets its default response: the caller is answered, never left waiting.
    ``quiet`` skips the per-call log line where the caller logs once for a whole episode (overload).
    """
    fields = response.get_fields_and_field_types()
    if "success" in fields:
        response.success = False
    if "message" in fields and fields["message"] == "string":
        response.message = reason
    if not quiet:
        log.warning("provided service call failed: %s", reason)
    return response
