"""One MQTT connection for the SDK: login, operator presence, subscriptions that survive reconnects.

paho forgets subscriptions when a clean session reconnects, and a robot
refuses commands from a user whose presence heartbeat is gone, so both are
restored on every CONNACK. Subscriptions wait for their SUBACK: a reply can
arrive milliseconds after a call is published, and a call made before the
broker has accepted the reply subscription would lose it. A refused
subscription (SUBACK 0x80, e.g. a wildcard a broker's ACL does not allow) is
reported to the caller and forgotten, not retried on every reconnect.

Reconnects retry transient failures (broker down, connection refused, CONNACK
3 "server unavailable") with a capped backoff, but not a refused login: a
changed password would otherwise become an endless loop that also feeds the
broker's per-address login throttle, slowing down every other client on the
machine. Such a refusal ends the connection for good (:attr:`Connection.failure`)
and is reported once through :attr:`Connection.on_failure`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import paho.mqtt.client as mqtt

from ..mqtt import (
    LOGIN_WAIT,
    BrokerRing,
    BrokerUrl,
    closed_before_connack,
    connack_refusal,
    login_refused,
    make_client,
    parse_broker_urls,
)
from ..topics import TopicTree
from .errors import ConnectError, LoginRefused, NotConnectedError
from .presence import OperatorPresence

log = logging.getLogger("roslink_mqtt.client")

Handler = Callable[[str, bytes, bool], None]  # (topic, payload, retained); runs on the network thread

# CONNACK refusals that a retry cannot fix (paho's reason codes for MQTT 3.1.1 return codes 2, 4 and 5), worded
# by roslink_mqtt.mqtt.connack_refusal. 1 (protocol version) is left to paho, which retries with MQTT 3.1;
# 3 (server unavailable) is transient.
PERMANENT_REFUSALS = frozenset({133, 134, 135})


@dataclass
class _Subscription:
    qos: int
    handlers: list[Handler] = field(default_factory=list)


class Connection:
    """A paho client plus the bookkeeping every SDK object needs.

    Handlers run on paho's network thread and must not block; they hand user
    work to a :class:`~roslink_mqtt.client.dispatch.CallbackQueue`.
    """

    def __init__(self, *, username: str, password: str | None, url: str | BrokerUrl | Sequence[str | BrokerUrl],
                 client_id: str,
                 topics: TopicTree, presence: bool = True, ca_file: str | None = None,
                 insecure_tls: bool = False, keepalive: int = 5) -> None:
        self.username, self.client_id, self.topics = username, client_id, topics
        urls = parse_broker_urls(url)
        self.keepalive = keepalive
        self.client = make_client(client_id, username=username, password=password, url=urls,
                                  ca_file=ca_file, insecure_tls=insecure_tls)
        self.brokers = BrokerRing(self.client, urls)  # failover: a lost connection moves on to the next node
        # Created before CONNECT: the presence last-will must be part of the CONNECT packet.
        self.presence = (OperatorPresence(self.client, username, client_id, topics=topics, commanding=False)
                         if presence else None)
        self._lock = threading.RLock()
        self._subs: dict[str, _Subscription] = {}
        self._pending_suback: dict[int, tuple[str, threading.Event, list[bool]]] = {}
        # Filters whose SUBACK a lost connection took along, with their waiters: RabbitMQ answers a filter outside
        # the login's grant by closing the connection (no SUBACK 0x80). Asked once more alone after reconnecting;
        # a second loss means refused (a network blip in the same moment twice is not the likely story).
        self._unanswered: dict[str, tuple[threading.Event, list[bool], int]] = {}
        self._connack = threading.Event()
        self._connack_failure: str | None = None
        self._connack_permanent = False
        self._closed_early = False  # the broker hung up before any CONNACK (a TLS port asked in plain MQTT, say)
        self._network_thread: int | None = None
        self.connected = threading.Event()
        self._closing = False
        self.ever_connected = False  # connect() succeeded once: from then on paho reconnects by itself
        self.down_since: float | None = None  # monotonic time the connection was lost (None while up)
        self.failure: LoginRefused | None = None  # a reconnect was refused for good; nothing will be sent again
        self.on_connected: list[Callable[[], None]] = []  # run on the network thread after every CONNACK
        self.on_failure: list[Callable[[LoginRefused], None]] = []  # run once, on the network thread
        self.on_suback: list[Callable[[str, bool], None]] = []  # (filter, granted) per SUBACK; network thread
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.client.on_subscribe = self._on_subscribe
        self.client.on_connect_fail = self._on_connect_fail

    @property
    def url(self) -> BrokerUrl:
        """The broker we are connected to (or trying next)."""
        return self.brokers.url

    def _move_on(self) -> BrokerUrl | None:
        return None if self._closing else self.brokers.advance()

    def _on_connect_fail(self, _client: mqtt.Client, _userdata: Any) -> None:
        self._move_on()

    # -- lifecycle --------------------------------------------------------------------
    def connect(self, timeout: float = LOGIN_WAIT) -> None:
        """Connect and wait for the broker to accept the login; raise ConnectError otherwise (LoginRefused for
        a refused login: "wrong username or password")."""
        unreachable: list[str] = []
        for _ in self.brokers.urls:  # the first node that answers; each refused one moves the ring on
            try:
                self.client.connect(self.url.host, self.url.port, keepalive=self.keepalive)
                break
            except (OSError, ValueError) as err:
                unreachable.append(f"{self.url}: {err}")
                self.brokers.advance()
        else:
            raise ConnectError(f"cannot reach the broker at {'; '.join(unreachable)}") from None
        self.client.loop_start()
        reason = self._await_connack(timeout)
        if reason is not None:
            self.client.disconnect()
            self.client.loop_stop()
            if self._connack_permanent:
                raise LoginRefused(f"broker {self.url} refused {self.username}: {reason}")
            raise ConnectError(f"broker {self.url}: {reason}")
        self.ever_connected = True
        if self.presence is not None:
            self.presence.start()

    def _await_connack(self, timeout: float) -> str | None:
        """Wait for the first CONNACK: None once accepted, else why not.

        A broker that hangs up before answering is asked once whether it speaks TLS: a ``mqtt://`` URL pointed at
        a TLS listener gets exactly that, and waiting out the timeout would only say "no answer".
        """
        deadline = time.monotonic() + timeout
        while not self._connack.wait(min(0.05, max(0.0, deadline - time.monotonic()))):
            if self._closed_early:
                return closed_before_connack(self.url)
            if time.monotonic() >= deadline:
                return f"no answer within {timeout:g} s"
        return self._connack_failure

    def close(self) -> None:
        """Sign off: clear our presence (robots stop trusting us at once), then disconnect."""
        self._closing = True
        if self.presence is not None:
            self.presence.stop()
        self.client.disconnect()
        self.client.loop_stop()
        self.connected.clear()

    def on_network_thread(self) -> bool:
        return threading.get_ident() == self._network_thread

    def require(self, what: str, *, now: bool = True) -> None:
        """Raise unless ``what`` can go out: NotConnectedError or LoginRefused, saying why nothing was sent.

        ``now=False`` accepts a connection that is down but reconnecting (subscriptions and
        service offers are restored on reconnect; commands and calls are not queued).
        """
        if self.failure is not None:
            raise LoginRefused(f"{what} not sent: {self.failure}")
        if self._closing:
            raise NotConnectedError(f"{what} not sent: the client was closed")
        if not self.ever_connected:
            raise NotConnectedError(f"{what} not sent: the client is not connected (call connect() first, or use "
                                    "`with RobotClient(...) as client:`)")
        if now and not self.connected.is_set():
            since = "" if self.down_since is None else f" {time.monotonic() - self.down_since:.1f} s ago"
            raise NotConnectedError(f"{what} not sent: the connection to {self.url} was lost{since}; "
                                    "reconnecting")

    # -- paho callbacks (network thread) -------------------------------------------------
    def _on_connect(self, client: mqtt.Client, _userdata: Any, _flags: Any, reason: Any, _props: Any) -> None:
        self._network_thread = threading.get_ident()
        if reason.is_failure:
            if not self.ever_connected:  # connect() is waiting: it raises
                self._connack_failure = connack_refusal(reason)
                self._connack_permanent = reason.value in PERMANENT_REFUSALS
                self._connack.set()
            elif reason.value in PERMANENT_REFUSALS and self.failure is None:
                self._give_up(client, reason)
            else:
                self._move_on()  # e.g. "server unavailable": a node shutting down; another may serve
            return
        with self._lock:
            # the filters a closed connection left unanswered go last, each in a SUBSCRIBE of its own: if the
            # broker closes the connection over one again, the others have their SUBACKs already
            subs = sorted(self._subs.items(), key=lambda item: item[0] in self._unanswered)
            for topic, sub in subs:
                result, mid = client.subscribe(topic, sub.qos)
                if result == mqtt.MQTT_ERR_SUCCESS and mid is not None:  # paho: a mid with every success
                    event, box, _ = self._unanswered.get(topic, (threading.Event(), [], 0))
                    self._pending_suback[mid] = (topic, event, box)
        if self.presence is not None:
            self.presence.beat()
        for hook in list(self.on_connected):
            try:
                hook()
            except Exception:
                log.exception("on_connected hook failed")
        self.down_since = None
        self.connected.set()
        self._connack.set()

    def _give_up(self, client: mqtt.Client, reason: Any) -> None:
        """A reconnect was refused for good: stop paho's retry loop and tell whoever listens, once."""
        text = connack_refusal(reason)
        fix = ("a changed password or a revoked grant will not fix itself" if login_refused(reason)
               else "retrying will not change the broker's answer")
        self.failure = LoginRefused(
            f"broker {self.url} refused the login of {self.username} ({text}) when reconnecting; not retrying: "
            f"{fix}, and each attempt counts against the broker's login throttle for this address")
        log.error("%s: %s", self.client_id, self.failure)
        client.disconnect()  # from a callback: loop_forever returns instead of reconnecting
        for hook in list(self.on_failure):
            try:
                hook(self.failure)
            except Exception:
                log.exception("on_failure hook failed")

    def _on_disconnect(self, _client: mqtt.Client, _userdata: Any, _flags: Any, reason: Any, _props: Any) -> None:
        if not self.ever_connected and not self._connack.is_set() and str(reason) != "Keep alive timeout":
            # the broker hung up on our CONNECT (paho's own keep-alive gave up instead on a broker that takes
            # longer than that to answer, e.g. a login throttle's delay: paho simply asks again)
            self._closed_early = True  # connect() is waiting: it finds out why
        if self.connected.is_set() and not self._closing:
            lost = self.url
            # closed over an unanswered SUBSCRIBE: the broker is alive and said no its way; stay on this node
            nxt = None if self._pending_suback else self._move_on()
            log.warning("%s: disconnected from %s (%s); reconnecting%s", self.client_id, lost, reason,
                        f" to {nxt}" if nxt else "")
        if self.connected.is_set():
            self.down_since = time.monotonic()
        self.connected.clear()
        self._suback_lost()

    def _suback_lost(self) -> None:
        """The connection ended with SUBSCRIBEs unanswered: keep their waiters for one more try, then refuse."""
        with self._lock:
            pending, self._pending_suback = self._pending_suback, {}
            for topic, event, box in pending.values():
                _, _, tries = self._unanswered.get(topic, (event, box, 0))
                if len(pending) > 1:  # several unanswered: nothing says which (if any) the broker objected to
                    self._unanswered[topic] = (event, box, tries)
                elif tries >= 1:
                    self._unanswered.pop(topic, None)
                    self._subs.pop(topic, None)
                    log.warning("%s: the broker closed the connection twice instead of answering SUBSCRIBE %s; "
                                "taken as refused (RabbitMQ does this for a filter outside the login's grant)",
                                self.client_id, topic)
                    box.append(False)
                    event.set()
                else:
                    self._unanswered[topic] = (event, box, tries + 1)

    def _on_subscribe(self, _client: mqtt.Client, _userdata: Any, mid: int, reasons: list[Any], _props: Any) -> None:
        with self._lock:
            pending = self._pending_suback.pop(mid, None)
            if pending is None:
                return
            topic, event, box = pending
            self._unanswered.pop(topic, None)
            granted = bool(reasons) and not any(r.is_failure for r in reasons)
            if not granted:
                self._subs.pop(topic, None)  # refused: do not ask again on every reconnect
            box.append(granted)
        event.set()
        for hook in list(self.on_suback):  # after a reconnect too: a refusal then is a grant removed meanwhile
            try:
                hook(topic, granted)
            except Exception:
                log.exception("on_suback hook failed")

    def _on_message(self, _client: mqtt.Client, _userdata: Any, msg: mqtt.MQTTMessage) -> None:
        topic = msg.topic
        with self._lock:
            handlers: dict[int, Handler] = {}
            for pattern, sub in self._subs.items():
                if mqtt.topic_matches_sub(pattern, topic):
                    for handler in sub.handlers:
                        handlers.setdefault(id(handler), handler)
        for handler in handlers.values():
            try:
                # paho types payload bytes | bytearray; a received message's is always bytes (struct.unpack)
                handler(topic, msg.payload, bool(msg.retain))  # type: ignore[arg-type]
            except Exception:
                log.exception("handler for %s failed", topic)

    # -- subscriptions -------------------------------------------------------------------
    def subscribe(self, topic: str, handler: Handler, qos: int = 1, timeout: float = 5.0) -> bool:
        """Route ``topic`` (a filter) to ``handler``; True once the broker granted it.

        Off the network thread this waits for the SUBACK; False means the
        broker refused the filter (0x80) or did not answer in time. While
        disconnected the filter is kept and subscribed on reconnect.
        """
        with self._lock:
            sub = self._subs.get(topic)
            if sub is not None:
                if handler not in sub.handlers:
                    sub.handlers.append(handler)
                return True
            self._subs[topic] = _Subscription(qos, [handler])
            result, mid = self.client.subscribe(topic, qos)
            if result != mqtt.MQTT_ERR_SUCCESS or mid is None:  # paho: a mid with every success
                return False  # not connected: _on_connect subscribes it
            event = threading.Event()
            box: list[bool] = []  # the SUBACK's verdict: granted or not
            self._pending_suback[mid] = (topic, event, box)
        if self.on_network_thread():
            return True  # cannot wait for our own thread; the SUBACK is handled when it comes
        if not event.wait(timeout):
            log.warning("%s: no SUBACK for %s within %g s", self.client_id, topic, timeout)
            return False
        return box[0]

    def subscribed(self) -> set[str]:
        """The filters we hold (granted, or waiting for a (re)connect); a refused one is not among them."""
        with self._lock:
            return set(self._subs)

    def unsubscribe(self, topic: str, handler: Handler) -> None:
        with self._lock:
            sub = self._subs.get(topic)
            if sub is None:
                return
            if handler in sub.handlers:
                sub.handlers.remove(handler)
            if not sub.handlers:
                del self._subs[topic]
                self.client.unsubscribe(topic)

    def publish(self, topic: str, payload: bytes, qos: int = 1, retain: bool = False) -> mqtt.MQTTMessageInfo:
        """Queue a message (paho sends it, or keeps QoS>0 ones for after a reconnect)."""
        return self.client.publish(topic, payload, qos=qos, retain=retain)
