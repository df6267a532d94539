"""A CONNECT read into a light session (roslink_mqtt/broker/connect.py, hardened fix 33): the same answers as
amqtt's own ``init_from_connect`` for every CONNECT, a connection state that behaves as amqtt's state machine,
and a refused attempt's session freed without the garbage collector."""

from __future__ import annotations

import asyncio
import gc
import weakref
from typing import Any

import pytest
from amqtt.adapters import BufferReader, BufferWriter
from amqtt.errors import MQTTError
from amqtt.mqtt.protocol.broker_handler import BrokerProtocolHandler
from amqtt.session import Session
from hypothesis import given, settings
from hypothesis import strategies as st
from transitions import MachineError

from roslink_mqtt.broker.connect import LightSession, read_connect

pytestmark = pytest.mark.unit

FIELDS = ("client_id", "clean_session", "will_flag", "will_retain", "will_qos", "will_topic", "will_message",
          "username", "password", "remote_address", "remote_port", "keep_alive")


class Plugins:
    """What read_connect asks of amqtt's PluginManager: events, recorded."""

    def __init__(self) -> None:
        self.events: list[tuple[Any, str]] = []

    async def fire_event(self, event: Any, **kwargs: Any) -> None:
        self.events.append((event, type(kwargs.get("packet")).__name__))


class Writer(BufferWriter):
    def __init__(self) -> None:
        super().__init__()
        self.written, self.closed = b"", False

    async def close(self) -> None:
        self.written, self.closed = self.get_buffer(), True


def utf8(text: str) -> bytes:
    raw = text.encode()
    return len(raw).to_bytes(2, "big") + raw


def connect_bytes(flags: int, client_id: str = "c1", *, name: str = "MQTT", level: int = 4, keep_alive: int = 30,
                  will: tuple[str, str] | None = None, username: str | None = None,
                  password: str | None = None) -> bytes:
    body = utf8(name) + bytes([level, flags]) + keep_alive.to_bytes(2, "big") + utf8(client_id)
    for text in (*(will or ()), username, password):
        if text is not None:
            body += utf8(text)
    head, n = bytearray([0x10]), len(body)
    while True:
        byte, n = n % 128, n // 128
        head.append(byte | 0x80 if n else byte)
        if not n:
            return bytes(head) + body


USER, PASS, WILL, CLEAN, RESERVED = 0x80, 0x40, 0x04, 0x02, 0x01
CONNECTS = {
    "a login": connect_bytes(USER | PASS | CLEAN, username="alice", password="pw"),
    "no login": connect_bytes(CLEAN),
    "a will": connect_bytes(USER | PASS | WILL | 0x08 | 0x20 | CLEAN, will=("t/w", "gone"), username="a",
                            password="b"),
    "keep-alive 0": connect_bytes(CLEAN, keep_alive=0),
    "persistent": connect_bytes(USER | PASS, "me", username="u", password="p"),
    "MQTT 3.1": connect_bytes(CLEAN, level=3),
    "a password without a user": connect_bytes(PASS | CLEAN, password="pw"),
    "no client id, not clean": connect_bytes(0, ""),
    "the reserved flag": connect_bytes(RESERVED | CLEAN),
    "another protocol name": connect_bytes(CLEAN, name="MQIsdp"),
}


async def read_both(raw: bytes) -> tuple[Any, Any]:
    """(stock outcome, ours): each the session's fields or the MQTTError, with what was written and fired."""
    async def outcome(read: Any) -> Any:
        plugins, writer = Plugins(), Writer()
        try:
            result = await read(BufferReader(raw), writer, plugins)
        except MQTTError as exc:
            return ("refused", str(exc), writer.written, writer.closed, plugins.events)
        session = result[1] if isinstance(result, tuple) else result
        return ({f: getattr(session, f) for f in FIELDS}, writer.get_buffer(), plugins.events)

    return await outcome(BrokerProtocolHandler.init_from_connect), await outcome(read_connect)


@pytest.mark.parametrize("name", CONNECTS)
def test_every_connect_gets_amqtts_own_answer(name: str) -> None:
    stock, ours = asyncio.run(read_both(CONNECTS[name]))
    assert ours == stock


def test_the_connects_above_are_both_let_in_and_refused() -> None:
    """(So that the comparison above compares both ways.)"""
    outcomes = [asyncio.run(read_both(raw))[1][0] == "refused" for raw in CONNECTS.values()]
    assert 3 <= sum(outcomes) <= len(outcomes) - 3


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from(["connect", "disconnect"]), max_size=8))
def test_the_connection_state_answers_as_amqtts_state_machine(steps: list[str]) -> None:
    stock, light = Session(), LightSession()
    for step in steps:
        results = []
        for session in (stock, light):
            try:
                getattr(session.transitions, step)()
                results.append("ok")
            except MachineError:
                results.append("refused")
        assert results[0] == results[1], (steps, step)
        for session in (stock, light):
            session.last_connect_time = session.last_connect_time and 1  # the same second for both
            session.last_disconnect_time = session.last_disconnect_time and 1
        observed = [(s.transitions.state, s.transitions.is_new(), s.transitions.is_connected(),
                     s.transitions.is_disconnected(), s.last_connect_time is None, s.last_disconnect_time is None)
                    for s in (stock, light)]
        assert observed[0] == observed[1], (steps, step)


def test_a_refused_attempts_session_is_freed_at_once() -> None:
    """amqtt's state machine holds its session in a reference cycle: every refused guess left garbage for the
    collector, paid for in the event loop. The light session goes when it is dropped."""
    gc.disable()
    try:
        stock, light = Session(), LightSession()
        stock_ref, light_ref = weakref.ref(stock), weakref.ref(light)
        del stock, light
        assert light_ref() is None
        assert stock_ref() is not None  # what fix 33 saves
    finally:
        gc.enable()
        gc.collect()
