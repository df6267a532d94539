"""Readers that keep one connection from holding the broker's event loop or memory.

amqtt 0.12.1 reads packets in small pieces (a SUBSCRIBE filter by filter, a header byte by
byte), so a limit on any single read never triggers: a 781 kB SUBSCRIBE of 200,000 filters
went through whole. :class:`PacketGate` follows the MQTT framing of the byte stream itself
and refuses a packet as soon as its fixed header announces more than that packet type may
carry -- before a byte of its body is read or buffered.

amqtt's WebSocket reader re-appends the last frame in a loop without yielding when the
peer closes mid-packet (``recv()`` raises ConnectionClosed, which it suppresses), so one
connection that announced 1 MB and sent 1 byte held the loop for seconds.
:class:`SafeWebSocketsReader` ends the read at the close instead.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Callable

from amqtt.adapters import ReaderAdapter, WebSocketsReader
from websockets import ConnectionClosed

log = logging.getLogger("roslink_mqtt.broker")

CONNECT, PUBLISH, SUBSCRIBE, UNSUBSCRIBE = 1, 3, 8, 10
PACKET_NAMES = {CONNECT: "CONNECT", PUBLISH: "PUBLISH", SUBSCRIBE: "SUBSCRIBE", UNSUBSCRIBE: "UNSUBSCRIBE"}


class PacketTooLarge(Exception):
    """A client announced a packet larger than the broker accepts; its connection is closed.

    Not an ``MQTTError``: amqtt's reader loop treats those as "discard and go on", which
    would leave the stream in the middle of a packet.
    """


class PacketGate(ReaderAdapter):
    """Pass-through reader that knows where each packet starts and refuses oversized ones.

    ``limit_for(packet_type)`` gives the largest remaining length accepted for a packet
    type (0 = no limit). The framing is MQTT 3.1.1 §2.2: one type byte, then a remaining
    length of 1-4 bytes (7 bits each, high bit = more), then that many bytes.
    """

    __slots__ = ("inner", "limit_for", "describe", "_state", "_type", "_length", "_shift", "_left")

    _TYPE, _LENGTH, _BODY = 0, 1, 2

    def __init__(self, inner: ReaderAdapter, limit_for: Callable[[int], int], describe: Callable[[], str]) -> None:
        self.inner, self.limit_for, self.describe = inner, limit_for, describe
        self._state, self._type, self._length, self._shift, self._left = self._TYPE, 0, 0, 0, 0

    async def read(self, n: int = -1) -> bytes:
        data = await self.inner.read(n)
        if data:
            self._follow(data)
        return data

    def feed_eof(self) -> None:
        self.inner.feed_eof()

    def _follow(self, data: bytes) -> None:
        i, size = 0, len(data)
        while i < size:
            if self._state == self._BODY:
                take = min(self._left, size - i)
                self._left -= take
                i += take
                if self._left == 0:
                    self._state = self._TYPE
                continue
            byte = data[i]
            i += 1
            if self._state == self._TYPE:
                self._type, self._length, self._shift, self._state = byte >> 4, 0, 0, self._LENGTH
                continue
            self._length |= (byte & 0x7F) << self._shift
            self._shift += 7
            if byte & 0x80 and self._shift < 28:
                continue
            self._header_done()

    def _header_done(self) -> None:
        limit = self.limit_for(self._type)
        if limit and self._length > limit:
            name = PACKET_NAMES.get(self._type, f"type {self._type}")
            log.warning("closing %s: %s of %d bytes announced, limit %d", self.describe(), name, self._length, limit)
            raise PacketTooLarge(f"{name} of {self._length} bytes > {limit}")
        self._left = self._length
        self._state = self._BODY if self._length else self._TYPE


class SafeWebSocketsReader(WebSocketsReader):
    """amqtt's WebSocket reader, except that a closed connection ends the read (no busy loop)."""

    async def _feed_buffer(self, n: int = 1) -> None:
        buffer = bytearray(self._stream.read())
        while len(buffer) < n:
            try:
                message = await self._protocol.recv()
            except ConnectionClosed:
                break
            buffer.extend(message.encode("utf-8") if isinstance(message, str) else message)
        self._stream = io.BytesIO(buffer)
