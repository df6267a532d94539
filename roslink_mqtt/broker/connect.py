"""A CONNECT read into a session that costs what a refused guess is worth (hardened fix 33).

amqtt builds a :class:`~amqtt.session.Session` for every CONNECT before the login is checked, and each Session
builds its own ``transitions`` state machine: about 150 µs of the event loop per attempt, and reference cycles
that only the garbage collector frees. During a password-guessing flood (thousands of refused attempts a
second, no login needed) that was a third of the broker's event loop, and the robots' traffic waited behind it
(docs/scaling.md). Here the connection's three states ("new", "connected", "disconnected") are a word in a small
object with the same calls amqtt and the hardened broker make (``state``, ``connect()``, ``disconnect()``,
``is_connected()``...), and the CONNECT's checks are stock 0.12.1's, in the same order, with the same answers.
"""

from __future__ import annotations

import weakref
from typing import Any

from amqtt.adapters import ReaderAdapter, WriterAdapter
from amqtt.errors import MQTTError
from amqtt.events import MQTTEvents
from amqtt.mqtt.connack import BAD_USERNAME_PASSWORD, IDENTIFIER_REJECTED, UNACCEPTABLE_PROTOCOL_VERSION, ConnackPacket
from amqtt.mqtt.connect import ConnectPacket
from amqtt.plugins.manager import PluginManager
from amqtt.session import Session
from amqtt.utils import format_client_message
from transitions import MachineError

MQTT_3_1_1 = 4  # the protocol level amqtt's broker speaks


class ConnectionState:
    """A session's connection state, with the calls of the ``transitions.Machine`` amqtt would build for it.

    ``connect()`` from "connected" raises :class:`~transitions.MachineError`, as the machine does (amqtt's client
    loop takes that for a client already connected); ``disconnect()`` is allowed from every state. Entering a
    state runs the session's own ``_on_enter_*`` hooks (its connect and disconnect times). The session is held
    weakly: no reference cycle, so a refused attempt's session is freed as soon as it is dropped.
    """

    __slots__ = ("_session", "state")

    def __init__(self, session: Session) -> None:
        self.state = "new"
        self._session = weakref.ref(session)

    def connect(self) -> None:
        if self.state == "connected":
            raise MachineError("Can't trigger event connect from state connected!")
        self.state = "connected"
        if (session := self._session()) is not None:
            session._on_enter_connected()  # noqa: SLF001 - the hook the machine would call

    def disconnect(self) -> None:
        self.state = "disconnected"
        if (session := self._session()) is not None:
            session._on_enter_disconnected()  # noqa: SLF001 - the hook the machine would call

    def is_new(self) -> bool:
        return self.state == "new"

    def is_connected(self) -> bool:
        return self.state == "connected"

    def is_disconnected(self) -> bool:
        return self.state == "disconnected"


class LightSession(Session):
    """An amqtt Session whose ``transitions`` is a :class:`ConnectionState`."""

    def _init_states(self) -> None:
        self.transitions: Any = ConnectionState(self)


def _refusal(connect: ConnectPacket, peer: str) -> tuple[int, str | None] | None:
    """Stock's answer to a CONNECT it refuses before any login check: (CONNACK code, what to raise), or None."""
    if connect.proto_level != MQTT_3_1_1:
        return UNACCEPTABLE_PROTOCOL_VERSION, f"Invalid protocol from {peer}: {connect.proto_level}"
    if not connect.username_flag and connect.password_flag:
        return BAD_USERNAME_PASSWORD, None  # MQTT-3.1.2-22
    if connect.username_flag and connect.username is None:
        return BAD_USERNAME_PASSWORD, f"Invalid username from {peer}"
    if connect.password_flag and connect.password is None:
        return BAD_USERNAME_PASSWORD, f"Invalid password from {peer}"
    if connect.clean_session_flag is False and connect.payload is not None and connect.payload.client_id_is_random:
        return IDENTIFIER_REJECTED, f"[MQTT-3.1.3-8] [MQTT-3.1.3-9] {peer}: No client Id provided (cleansession=0)"
    return None


async def read_connect(reader: ReaderAdapter, writer: WriterAdapter, plugins: PluginManager[Any]) -> LightSession:
    """Read a client's CONNECT and make its (not yet authenticated) session; what stock ``init_from_connect`` did,
    packet for packet, but the session is a :class:`LightSession`. Raises MQTTError when the CONNECT is refused
    (after answering it, where stock answers)."""
    connect = await ConnectPacket.from_stream(reader)
    await plugins.fire_event(MQTTEvents.PACKET_RECEIVED, packet=connect)
    header, payload = connect.variable_header, connect.payload
    if header is None:
        raise MQTTError("CONNECT packet: variable header not initialized.")
    if payload is None:
        raise MQTTError("CONNECT packet: payload not initialized.")
    if payload.client_id is None:
        raise MQTTError("[[MQTT-3.1.3-3]] : Client identifier must be present")
    if header.will_flag and (payload.will_topic is None or payload.will_message is None):
        raise MQTTError("Will flag set, but will topic/message not present in payload")
    if header.reserved_flag:
        raise MQTTError("[MQTT-3.1.2-3] CONNECT reserved flag must be set to 0")
    if connect.proto_name != "MQTT":
        raise MQTTError(f'[MQTT-3.1.2-1] Incorrect protocol name: "{connect.proto_name}"')

    remote = writer.get_peer_info()
    remote_address, remote_port = remote if remote is not None else (None, None)
    peer = format_client_message(address=remote_address, port=remote_port)
    if (refusal := _refusal(connect, peer)) is not None:
        code, error = refusal
        connack = ConnackPacket.build(0, code)
        await plugins.fire_event(MQTTEvents.PACKET_SENT, packet=connack)
        await connack.to_stream(writer)
        await writer.close()
        raise MQTTError(error)

    session = LightSession()
    session.client_id = connect.client_id
    session.clean_session = connect.clean_session_flag
    session.will_flag = connect.will_flag
    session.will_retain = connect.will_retain_flag
    session.will_qos = connect.will_qos
    session.will_topic = connect.will_topic
    session.will_message = connect.will_message
    session.username = connect.username
    session.password = connect.password
    session.remote_address = remote_address
    session.remote_port = remote_port
    session.ssl_object = writer.get_ssl_info()
    session.keep_alive = max(connect.keep_alive, 0)
    return session
