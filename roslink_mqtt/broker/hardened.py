"""amqtt's Broker with the gaps of amqtt 0.12.1 closed (pinned: ``amqtt==0.12.1`` in pyproject.toml).

Each fix below was reproduced on stock 0.12.1 first and has a regression test in
``tests/test_broker_hardening.py``. They are subclass overrides -- nothing in amqtt is
monkeypatched, so a plain ``amqtt.broker.Broker`` in the same process keeps its stock
behaviour.

1. **Keep-alive** (MQTT-3.1.2-24). Stock ``BrokerProtocolHandler.handle_read_timeout`` is
   a no-op, so a frozen client (SIGSTOP, cut cable) is never dropped and its will never
   fires. :class:`HardenedHandler` aborts the transport and reports an abnormal
   disconnect; the session's keep-alive is multiplied by 1.5 first.
2. **Retained messages** go out only when a subscription is made (MQTT-3.3.1-6), only
   for that session's own filter, only if the session may receive the topic, at
   ``min(granted QoS, message QoS)``. Stock sends every session, right after CONNACK,
   the retained messages matching *any* filter in the broker (anybody's), unchecked.
3. **QoS of deliveries** is ``min(publish QoS, subscription QoS)`` (MQTT-3.3.5);
   stock uses the subscriber's. One copy per session for overlapping filters.
4. **Authentication before the session table is touched.** Stock deletes or takes
   over the session of a client id before checking the password, so a wrong password
   with a victim's client id wipes the victim's subscriptions; failed logins also
   leave "connected" zombie sessions.
5. **Client-id take-over** (MQTT-3.1.4-2) closes the old connection first (stock leaves
   it open, or breaks the new one). No will is published on take-over: the client is
   alive, it reconnected.
6. **A persistent session is resumed only by the login that made it** (stock lets
   another user with the same client id inherit its subscriptions and queued messages).
7. **Will topic** is checked against the PUBLISH ACL at CONNECT (stock never checks wills).
8. **Broadcast vs. concurrent SUBSCRIBE**: stock awaits the ACL while iterating the
   subscription dict; a SUBSCRIBE meanwhile raises "dictionary changed size" and the
   message is lost for the remaining filters. Matching sessions are snapshotted first.
9. **Messages queued for an offline session** are replayed with retain=0 (stock: 1)
   and re-checked against the ACL (a grant may have been revoked meanwhile).
10. **CONNECT timeout**: a connection that sends no CONNECT is closed after
    ``connect_timeout`` (stock holds it forever).
11. **ACL dispatch** awaits the topic plugins inline; stock creates a Task per plugin
    per check, twice per message, which cost ~25 % of throughput.
12. **Failed start** (port in use) closes the listeners that did bind (stock leaves them
    open and refuses ``shutdown()``).
13. **Publishing to ``$`` topics** is dropped like any denied publish, as Mosquitto does
    (stock closes the connection), and payloads over ``max_payload`` are dropped. A packet
    larger than ``max_payload`` plus the largest possible topic closes the connection
    before it is read (stock buffers up to the protocol's 256 MB per packet).

amqtt internals relied on (re-diff all of them on any amqtt upgrade):

* ``Broker``: ``_initialize_client_session`` (replaced; the part after authentication
  mirrors stock), ``_authenticate`` (replaced), ``_client_connected`` (wrapped),
  ``_handle_message_delivery`` (wrapped), ``_broadcast_message`` and ``_run_broadcast``
  (replaced), ``_handle_subscription`` (wrapped),
  ``_publish_retained_messages_for_subscription`` and ``_publish_session_retained_messages``
  (replaced), ``_topic_filtering`` (replaced), ``_handle_disconnect`` (wrapped), ``start``
  (wrapped); read or called: ``_sessions``, ``_subscriptions``, ``_retained_messages``,
  ``_broadcast_queue``, ``_servers``, ``_get_handler``, ``_matches``, ``_delete_session``,
  ``_retain_broadcast_message``, ``plugins_manager._topic_plugins``.
* The broadcast dict keys ``session``/``topic``/``data``/``qos`` (we add ``pub_qos``).
* ``BrokerProtocolHandler.init_from_connect`` (a classmethod that builds ``cls(...)``),
  ``handle_read_timeout``, ``handle_connection_closed``, ``attach``; the reader loop reads
  ``session.keep_alive`` once, when the handler starts, as its read timeout, ends the
  connection on an exception other than MQTTError/NoDataError/TimeoutError, and
  ``PublishPayload.from_stream`` reads a payload with one ``reader.read(length)``.
* ``StreamWriterAdapter._writer`` (asyncio StreamWriter), ``WebSocketsWriter._protocol``
  (websockets ServerConnection): to abort a transport whose peer is frozen.
* ``Session.attributes`` (amqtt's documented per-session dict) for our state:
  ``roslink.*`` keys.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
from typing import Any

from amqtt.adapters import ReaderAdapter, StreamWriterAdapter, WebSocketsWriter, WriterAdapter
from amqtt.broker import Broker
from amqtt.contexts import Action
from amqtt.errors import AMQTTError, MQTTError, NoDataError
from amqtt.events import MQTTEvents
from amqtt.mqtt.connack import NOT_AUTHORIZED, ConnackPacket
from amqtt.mqtt.constants import QOS_1, QOS_2
from amqtt.mqtt.disconnect import DisconnectPacket
from amqtt.mqtt.protocol.broker_handler import BrokerProtocolHandler
from amqtt.session import Session
from amqtt.utils import gen_client_id

log = logging.getLogger("roslink_mqtt.broker")

AMQTT_VERSION = "0.12.1"  # the version every override above was written against
KEEPALIVE_FACTOR = 1.5  # MQTT-3.1.2-24: drop after 1.5 x keep-alive without a packet
CONNECT_TIMEOUT = 10.0  # s from TCP accept to a complete CONNECT
TAKEOVER_WAIT = 2.0  # s to wait for the previous connection of a client id to wind down

# Session.attributes keys
ATTR_KEEPALIVE = "roslink.keep_alive"  # the keep-alive the client asked for (session.keep_alive holds x1.5)
ATTR_AUTH_OK = "roslink.auth_ok"  # verdict computed before the session table was touched
ATTR_DENY_REASON = "roslink.deny_reason"  # set by auth plugins for the refusal log line
ATTR_LISTENER = "roslink.listener"
_ATTR_LOGGED = "roslink.logged"

_PUB_QOS: contextvars.ContextVar[int | None] = contextvars.ContextVar("roslink_pub_qos", default=None)
_IN_SUBSCRIBE: contextvars.ContextVar[bool] = contextvars.ContextVar("roslink_in_subscribe", default=False)
_LISTENER: contextvars.ContextVar[str] = contextvars.ContextVar("roslink_listener", default="?")


def abort_transport(writer: WriterAdapter | None) -> None:
    """Close a connection at once, without flushing: a frozen peer cannot block it."""
    transport = None
    if isinstance(writer, StreamWriterAdapter):
        transport = writer._writer.transport
    elif isinstance(writer, WebSocketsWriter):
        transport = getattr(writer._protocol, "transport", None)
    if transport is not None:
        transport.abort()


async def _close_quietly(writer: WriterAdapter) -> None:
    try:
        await asyncio.wait_for(writer.close(), 2)
    except Exception:  # noqa: BLE001 - the peer may be gone or frozen; abort instead
        abort_transport(writer)


def describe_session(session: Session) -> str:
    return (f"client_id={session.client_id!r} user={session.username!r} "
            f"peer={session.remote_address}:{session.remote_port} via {session.attributes.get(ATTR_LISTENER, '?')}")


def _log_once(session: Session, key: str, level: int, message: str, *args: Any) -> None:
    """Log an abnormal per-message event once per session and key (no per-message log spam)."""
    seen: set[str] = session.attributes.setdefault(_ATTR_LOGGED, set())
    if key in seen or len(seen) > 256:
        return
    seen.add(key)
    log.log(level, message, *args)


MAX_TOPIC_OVERHEAD = 2 + 65535 + 2  # topic length prefix, longest topic, packet id


class PacketTooLarge(Exception):
    """A client announced a packet larger than the broker accepts; its connection is closed."""


class BoundedReader(ReaderAdapter):
    """Refuses any single read larger than ``limit`` bytes.

    amqtt reads a PUBLISH payload with one ``read(announced length)``, so this stops a client
    from making the broker buffer up to 256 MB (the MQTT maximum) per packet. The exception
    ends amqtt's reader loop, which closes the connection (an abnormal disconnect).
    """

    def __init__(self, inner: ReaderAdapter, limit: int, describe: Any) -> None:
        self.inner, self.limit, self.describe = inner, limit, describe

    async def read(self, n: int = -1) -> bytes:
        if n > self.limit:
            log.warning("closing %s: packet of %d bytes announced, limit %d", self.describe(), n, self.limit)
            raise PacketTooLarge(n)
        return await self.inner.read(n)

    def feed_eof(self) -> None:
        self.inner.feed_eof()


class HardenedHandler(BrokerProtocolHandler):
    """Broker-side protocol handler that enforces keep-alive (fix 1).

    amqtt's reader loop already wraps every fixed-header read in
    ``wait_for(..., timeout=session.keep_alive)`` and calls ``handle_read_timeout()`` when it
    expires -- a no-op in 0.12.1. Here the transport is aborted (so closing cannot wait on a
    frozen peer's receive window) and the broker's disconnect waiter gets ``None``: an
    abnormal disconnect, which publishes the will.
    """

    _expired = False
    _closing: asyncio.Task[None] | None = None
    read_limit = 0  # bytes per read; 0 = unlimited (set by the broker before attach)

    def attach(self, session: Session, reader: ReaderAdapter, writer: WriterAdapter) -> None:
        if self.read_limit:
            reader = BoundedReader(reader, self.read_limit, lambda: describe_session(session))
        super().attach(session, reader, writer)

    def handle_read_timeout(self) -> None:
        if self._expired:
            return
        self._expired = True
        session = self.session
        if session is not None:
            log.warning("keep-alive expired: no packet for %.1f s from %s; dropping it",
                        float(session.keep_alive), describe_session(session))
        abort_transport(self.writer)
        self._closing = asyncio.get_running_loop().create_task(self.handle_connection_closed())


class HardenedBroker(Broker):
    """amqtt ``Broker`` with the fixes listed in the module docstring.

    ``max_payload`` (bytes, 0 = unlimited) drops larger PUBLISH payloads; ``connect_timeout``
    bounds the wait for CONNECT.
    """

    def __init__(self, config: dict[str, Any], *, connect_timeout: float = CONNECT_TIMEOUT,
                 max_payload: int = 0) -> None:
        super().__init__(config)
        self.connect_timeout = connect_timeout
        self.max_payload = max_payload

    # -- fix 12: a failed start leaves nothing listening -------------------------------
    async def start(self) -> None:
        try:
            await super().start()
        except Exception:
            for server in self._servers.values():
                await server.close_instance()
            self._servers.clear()
            raise

    async def _client_connected(self, listener_name: str, reader: ReaderAdapter, writer: WriterAdapter) -> None:
        _LISTENER.set(listener_name)  # this task serves one connection: name it in its log lines
        await super()._client_connected(listener_name, reader, writer)

    # -- fixes 1, 4, 5, 6, 7, 10: CONNECT handling ---------------------------------------
    async def _initialize_client_session(self, reader: ReaderAdapter, writer: WriterAdapter,
                                         remote_address: str, remote_port: int
                                         ) -> tuple[BrokerProtocolHandler, Session]:
        peer = f"{remote_address}:{remote_port}"
        try:
            handler, session = await asyncio.wait_for(
                HardenedHandler.init_from_connect(reader, writer, self.plugins_manager),
                timeout=self.connect_timeout)
        except TimeoutError as exc:
            log.warning("no CONNECT from %s within %.0f s; closing", peer, self.connect_timeout)
            await _close_quietly(writer)
            raise AMQTTError("connect timeout") from exc
        except MQTTError as exc:
            await _close_quietly(writer)
            raise MQTTError(exc) from exc
        except (AMQTTError, NoDataError) as exc:
            raise AMQTTError(exc) from exc
        session.attributes[ATTR_LISTENER] = _LISTENER.get()
        if self.max_payload and isinstance(handler, HardenedHandler):
            handler.read_limit = self.max_payload + MAX_TOPIC_OVERHEAD

        reason = await self._admit(session)
        if reason is not None:
            log.warning("refused %s: %s", describe_session(session), reason)
            connack = ConnackPacket.build(0, NOT_AUTHORIZED)
            try:
                await connack.to_stream(writer)
                await self.plugins_manager.fire_event(MQTTEvents.PACKET_SENT, packet=connack)
            except Exception:  # noqa: BLE001 - the peer may already be gone
                pass
            finally:
                await _close_quietly(writer)
            raise MQTTError(f"{peer}: not authorized")

        if session.client_id:
            await self._take_over(session.client_id)

        # From here on: stock 0.12.1 logic, plus fix 6 and the keep-alive factor.
        resumed = False
        if session.clean_session:
            if session.client_id:
                await self._delete_session(session.client_id)
            else:
                session.client_id = gen_client_id()
        elif session.client_id in self._sessions:
            existing, _ = self._sessions[session.client_id]
            if existing.username != session.username:
                log.info("client_id=%r: persistent session of %r not resumed by %r; starting a new one",
                         session.client_id, existing.username, session.username)
                await self._delete_session(session.client_id)
            else:
                for attr in ("will_flag", "will_message", "will_topic", "will_qos", "will_retain", "keep_alive",
                             "password", "remote_address", "remote_port", "ssl_object"):
                    setattr(existing, attr, getattr(session, attr))
                existing.attributes.update(session.attributes)
                session, resumed = existing, True
        session.parent = 1 if resumed else 0

        session.attributes[ATTR_KEEPALIVE] = session.keep_alive
        if session.keep_alive > 0:
            # the handler's reader loop uses session.keep_alive as its read timeout
            session.keep_alive = session.keep_alive * KEEPALIVE_FACTOR  # type: ignore[assignment]
        session.attributes[ATTR_AUTH_OK] = True
        log.info("connected %s keepalive=%ss clean=%d%s", describe_session(session), session.attributes[ATTR_KEEPALIVE],
                 int(session.clean_session), " (session resumed)" if resumed else "")
        return handler, session

    async def _admit(self, session: Session) -> str | None:
        """None when the session may connect, else why not (fixes 4 and 7)."""
        if not await Broker._authenticate(self, session, None):  # type: ignore[arg-type]
            return session.attributes.pop(ATTR_DENY_REASON, None) or "authentication failed"
        if session.will_flag and session.will_topic is not None:
            will = session.will_topic
            if will.startswith("$") or not await self._topic_filtering(session, will, Action.PUBLISH):
                return f"will topic {will!r} is not writable for this login"
        return None

    async def _take_over(self, client_id: str) -> None:
        """Fix 5: end a live connection with the same client id before its session is reused."""
        entry = self._sessions.get(client_id)
        if entry is None or entry[0].transitions.state != "connected":
            return
        old_session, old_handler = entry
        log.info("client_id=%r connected again; closing its previous connection (no will)", client_id)
        old_session.will_flag = False
        abort_transport(old_handler.writer)
        await old_handler.handle_connection_closed()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + TAKEOVER_WAIT
        while old_session.transitions.state == "connected" and loop.time() < deadline:
            await asyncio.sleep(0.01)  # its client loop runs _handle_disconnect
        if old_session.transitions.state == "connected":
            try:
                old_session.transitions.disconnect()
            except Exception:  # noqa: BLE001 - already moving to disconnected
                pass

    async def _authenticate(self, session: Session, _listener: Any) -> bool:
        # The verdict was computed in _initialize_client_session, before any state change.
        return bool(session.attributes.pop(ATTR_AUTH_OK, False))

    async def _handle_disconnect(self, client_session: Session, handler: BrokerProtocolHandler,
                                 disconnect_waiter: asyncio.Future[Any]) -> None:
        clean = isinstance(disconnect_waiter.result(), DisconnectPacket)
        will = not clean and client_session.will_flag
        await super()._handle_disconnect(client_session, handler, disconnect_waiter)
        log.info("disconnected %s: %s", describe_session(client_session),
                 "DISCONNECT" if clean else "connection lost" + (", will published" if will else ""))

    # -- fixes 3 and 13: PUBLISH from a client ----------------------------------------------
    async def _handle_message_delivery(self, client_session: Session, handler: BrokerProtocolHandler,
                                       wait_deliver: asyncio.Future[Any]) -> bool:
        message = wait_deliver.result()
        if message is not None and message.topic:
            if message.topic.startswith("$"):
                _log_once(client_session, "$" + message.topic, logging.INFO,
                          "deny publish %s topic=%r: '$' topics are the broker's", describe_session(client_session),
                          message.topic)
                return True
            if self.max_payload and message.data is not None and len(message.data) > self.max_payload:
                _log_once(client_session, "size", logging.WARNING, "dropped publish %s topic=%r: %d bytes > %d",
                          describe_session(client_session), message.topic, len(message.data), self.max_payload)
                return True
        token = _PUB_QOS.set(getattr(message, "qos", None))
        try:
            return await super()._handle_message_delivery(client_session, handler, wait_deliver)
        finally:
            _PUB_QOS.reset(token)

    async def _broadcast_message(self, session: Session | None, topic: str | None,
                                 data: bytes | bytearray | None, force_qos: int | None = None) -> None:
        broadcast: dict[str, Any] = {"session": session, "topic": topic, "data": data}
        if force_qos is not None:
            broadcast["qos"] = force_qos  # will message or internal broadcast
        elif (pub_qos := _PUB_QOS.get()) is not None:
            broadcast["pub_qos"] = pub_qos  # a client's PUBLISH (set by _handle_message_delivery)
        await self._broadcast_queue.put(broadcast)

    # -- fixes 3, 8: fan-out ----------------------------------------------------------------
    async def _run_broadcast(self, running_tasks: Any) -> None:
        broadcast = await self._broadcast_queue.get()
        topic: str = broadcast["topic"]
        pub_qos = broadcast.get("qos", broadcast.get("pub_qos"))

        # Snapshot first: awaiting the ACL while iterating _subscriptions races SUBSCRIBE.
        targets: dict[str, tuple[Session, int]] = {}
        for topic_filter, subscribers in self._subscriptions.items():
            if not self._matches(topic, topic_filter):
                continue
            for target, sub_qos in subscribers:
                previous = targets.get(target.client_id)
                if previous is None or sub_qos > previous[1]:
                    targets[target.client_id] = (target, sub_qos)

        for target, sub_qos in targets.values():
            if not await self._topic_filtering(target, topic=topic, action=Action.RECEIVE):
                continue
            qos = sub_qos if pub_qos is None else min(pub_qos, sub_qos)
            state = target.transitions.state
            if state != "connected":
                if not target.clean_session and qos in (QOS_1, QOS_2) and not target.is_anonymous:
                    await self._retain_broadcast_message(broadcast, qos, target)
                continue
            handler = self._get_handler(target)
            if handler is not None:
                running_tasks.append(asyncio.ensure_future(
                    handler.mqtt_publish(topic, broadcast["data"], qos, retain=False)))

    # -- fix 9: messages queued while a persistent session was offline ---------------------
    async def _publish_session_retained_messages(self, session: Session) -> None:
        handler = self._get_handler(session)
        if handler is None:
            return
        tasks = []
        while not session.retained_messages.empty():
            queued = session.retained_messages.get_nowait()
            if not await self._topic_filtering(session, topic=queued.topic, action=Action.RECEIVE):
                continue
            tasks.append(asyncio.ensure_future(
                handler.mqtt_publish(queued.topic, queued.data, queued.qos, retain=False)))
        if tasks:
            await asyncio.wait(tasks)

    # -- fix 2: retained messages -----------------------------------------------------------
    async def _handle_subscription(self, client_session: Session, handler: BrokerProtocolHandler,
                                   subscribe_waiter: asyncio.Future[Any]) -> None:
        token = _IN_SUBSCRIBE.set(True)
        try:
            await super()._handle_subscription(client_session, handler, subscribe_waiter)
        finally:
            _IN_SUBSCRIBE.reset(token)

    async def _publish_retained_messages_for_subscription(self, subscription: tuple[str, int],
                                                          session: Session) -> None:
        # Stock also calls this right after CONNACK for every filter in the broker's
        # subscription table (anybody's). Only a SUBSCRIBE of this session may send retained.
        if not _IN_SUBSCRIBE.get():
            return
        topic_filter = subscription[0]
        granted = next((qos for s, qos in self._subscriptions.get(topic_filter, ())
                        if s.client_id == session.client_id), None)
        handler = self._get_handler(session)
        if granted is None or handler is None:
            return
        tasks = []
        for topic, retained in list(self._retained_messages.items()):
            if not self._matches(topic, topic_filter):
                continue
            if not await self._topic_filtering(session, topic=topic, action=Action.RECEIVE):
                continue
            qos = granted if retained.qos is None else min(granted, retained.qos)
            tasks.append(asyncio.ensure_future(handler.mqtt_publish(retained.topic, retained.data, qos, retain=True)))
        if tasks:
            await asyncio.wait(tasks)

    # -- fix 11: inline ACL dispatch ---------------------------------------------------------
    _topic_checks: list[Any] | None = None  # bound topic_filtering methods, found on first use

    async def _topic_filtering(self, session: Session, topic: str, action: Action) -> bool:
        # Same semantics as stock (every topic plugin must return a truthy value; None
        # denies), without a Task per plugin per check, and without re-reading the
        # plugin configuration on every message.
        checks = self._topic_checks
        if checks is None:
            manager = self.plugins_manager
            checks = self._topic_checks = ([plugin.topic_filtering for plugin in manager._topic_plugins]
                                           if manager.is_topic_filtering_enabled() else [])
        for check in checks:
            if not await check(session=session, topic=topic, action=action):
                return False
        return True

    # -- administration -----------------------------------------------------------------------
    async def disconnect_user(self, username: str) -> int:
        """Drop every live connection of ``username`` (e.g. a login removed on reload); wills fire."""
        dropped = 0
        for session, handler in list(self._sessions.values()):
            if session.username == username and session.transitions.state == "connected":
                abort_transport(handler.writer)
                await handler.handle_connection_closed()
                dropped += 1
        return dropped

    def connected_sessions(self) -> list[Session]:
        return [s for s, _ in self._sessions.values() if s.transitions.state == "connected"]
