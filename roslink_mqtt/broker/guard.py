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

A packet body is buffered until its last byte arrives, and amqtt's keep-alive does not run
while a packet is half read: 31 connections of one viewer, each announcing a 4 MiB PUBLISH
and stopping one byte short, pinned +124 MB until they closed. :class:`PacketGate` reads a
large body in pieces, charges them to the login's :class:`PartialBudget` and closes a
connection whose next piece would overdraw it or does not arrive in time.
"""

from __future__ import annotations

import asyncio
import io
import logging
import time
from collections.abc import Callable

from amqtt.adapters import ReaderAdapter, WebSocketsReader
from websockets import ConnectionClosed

log = logging.getLogger("roslink_mqtt.broker")

CONNECT, PUBLISH, SUBSCRIBE, UNSUBSCRIBE = 1, 3, 8, 10
PACKET_NAMES = {CONNECT: "CONNECT", PUBLISH: "PUBLISH", SUBSCRIBE: "SUBSCRIBE", UNSUBSCRIBE: "UNSUBSCRIBE"}
MQTT_311 = 4  # the CONNECT protocol level of MQTT 3.1.1, the one this broker speaks
MAX_PROTOCOL_HEAD = 16  # bytes of a CONNECT read for its protocol name and level ("MQTT": 7)
READ_CHUNK = 64 * 1024  # a body read larger than this is read, charged and timed in pieces of this size


class PacketRefused(Exception):
    """A packet the broker will not read further; the connection is closed.

    Not an ``MQTTError``: amqtt's reader loop treats those as "discard and go on", which
    leaves the stream in the middle of a packet -- that is how a wildcard PUBLISH topic was
    silently dropped, its payload then read as further packets, and a QoS 1 sender hung.
    """


class PacketTooLarge(PacketRefused):
    """A client announced a packet larger than the broker accepts."""


class BadTopic(PacketRefused):
    """A PUBLISH topic with a wildcard or U+0000 (MQTT-3.3.2-2, MQTT-1.5.3-2)."""


class PacketStalled(PacketRefused):
    """A large packet whose next piece did not arrive in time, or would overdraw its login's budget."""


class UnsupportedProtocol(PacketRefused):
    """A CONNECT for a protocol level other than MQTT 3.1.1's (4): answered with CONNACK 0x01 at once.

    amqtt decodes the whole CONNECT as 3.1.1 before it looks at the level; an MQTT 5 CONNECT's properties shift
    every field after them, and the decoder waited for bytes that never came (a 10 s hang, then "no CONNECT").
    """

    def __init__(self, level: int) -> None:
        self.level = level
        name = {3: "MQTT 3.1", 5: "MQTT 5"}.get(level, f"protocol level {level}")
        super().__init__(f"{name} CONNECT; this broker speaks MQTT 3.1.1 (protocol level 4)")


class Pacer:
    """A token bucket of PUBLISH packets shared by every connection of one login (``user_publish_rate``).

    A login over its rate is not disconnected and nothing it sent is dropped: the broker stops reading its
    connections until the allowance refills, so TCP pushes the backlog back to the sender. One connection
    flooding small messages cost the loop all its time (30,000 PUBLISHes a second from one paho client
    delayed every other client's messages by ~0.8 s); paced, it gets its share and the others theirs.
    """

    __slots__ = ("rate", "burst", "tokens", "at")

    def __init__(self, rate: float, burst: int) -> None:
        if not rate > 0 or burst < 1:
            raise ValueError(f"a pacer needs rate > 0 and burst >= 1, got {rate!r}, {burst!r}")
        self.rate, self.burst = rate, float(burst)
        self.tokens, self.at = self.burst, time.monotonic()

    def wait_for(self, packets: int, now: float) -> float:
        """Spend ``packets`` tokens; seconds to wait before reading on (0: within the allowance).

        The debt never grows beyond what was just read: the caller waits it off before reading more.
        """
        self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate) - packets
        self.at = now
        if self.tokens >= 0:
            return 0.0
        wait = -self.tokens / self.rate
        self.tokens, self.at = 0.0, now + wait  # the debt is paid by the wait
        return wait


class PartialBudget:
    """Bytes that packets still arriving may hold, shared by every connection of one login (``max_partial_bytes``).

    A body is kept in memory until its last byte has arrived; without a bound per login, one viewer's half-sent
    PUBLISHes pinned 4 MiB per connection for as long as it kept them open.
    """

    __slots__ = ("limit", "held")

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError(f"a partial-packet budget needs limit >= 1, got {limit!r}")
        self.limit, self.held = limit, 0

    def take(self, size: int) -> bool:
        """Charge ``size`` bytes; False (nothing charged) when that would exceed the limit."""
        if self.held + size > self.limit:
            return False
        self.held += size
        return True

    def give(self, size: int) -> None:
        self.held -= size


class PacketGate(ReaderAdapter):
    """Pass-through reader that knows where each packet starts and refuses oversized ones.

    ``limit_for(packet_type)`` gives the largest remaining length accepted for a packet
    type (0 = no limit). The framing is MQTT 3.1.1 §2.2: one type byte, then a remaining
    length of 1-4 bytes (7 bits each, high bit = more), then that many bytes. A PUBLISH
    topic (the first 2 + n bytes of its body) is checked for wildcards and NUL as it passes.
    ``describe`` names the connection in the log line; the broker replaces it after login, and sets
    ``pacer`` for a login whose PUBLISH rate is bounded (:class:`Pacer`) and ``budget`` (:class:`PartialBudget`).
    A read of more than :data:`READ_CHUNK` bytes (a large body) goes in pieces: each is charged to ``budget``
    while the body is incomplete and must arrive within ``piece_timeout`` seconds (0: no limit), so a packet
    may take longer the larger it is, and one that stops arriving is closed instead of held.
    """

    __slots__ = ("inner", "limit_for", "describe", "pacer", "budget", "piece_timeout", "_published", "_state",
                 "_type", "_length", "_shift", "_left", "_topic", "_connect")

    _TYPE, _LENGTH, _BODY = 0, 1, 2

    def __init__(self, inner: ReaderAdapter, limit_for: Callable[[int], int], describe: Callable[[], str]) -> None:
        self.inner, self.limit_for, self.describe = inner, limit_for, describe
        self.pacer: Pacer | None = None
        self.budget: PartialBudget | None = None
        self.piece_timeout = 0.0
        self._published = 0  # PUBLISH headers seen in the current read
        self._state, self._type, self._length, self._shift, self._left = self._TYPE, 0, 0, 0, 0
        self._topic: bytearray | None = None  # a PUBLISH topic being read (length prefix included)
        self._connect: bytearray | None = None  # a CONNECT's protocol name and level being read

    async def read(self, n: int = -1) -> bytes:
        if n > READ_CHUNK:
            data = await self._read_in_pieces(n)
        else:
            data = await self.inner.read(n)
            if data:
                self._follow(data)
        if data:
            if self._published and self.pacer is not None:
                wait = self.pacer.wait_for(self._published, time.monotonic())
                self._published = 0
                if wait > 0:
                    await asyncio.sleep(wait)
        return data

    def feed_eof(self) -> None:
        self.inner.feed_eof()

    async def _read_in_pieces(self, n: int) -> bytes:
        """``n`` bytes read :data:`READ_CHUNK` at a time, charged to the login's budget until all have arrived."""
        pieces: list[bytes] = []
        got = charged = 0
        budget = self.budget
        try:
            while got < n:
                want = min(READ_CHUNK, n - got)
                if budget is not None:
                    if not budget.take(want):
                        why = (f"packets still arriving on this login's connections hold {budget.held} bytes, "
                               f"limit {budget.limit}")
                        log.warning("closing %s: %s", self.describe(), why)
                        raise PacketStalled(why)
                    charged += want
                if self.piece_timeout > 0:
                    try:
                        piece = await asyncio.wait_for(self.inner.read(want), self.piece_timeout)
                    except TimeoutError:
                        why = (f"{want} bytes of a {n}-byte packet body did not arrive within {self.piece_timeout:g} s "
                               f"({got} arrived)")
                        log.warning("closing %s: %s", self.describe(), why)
                        raise PacketStalled(why) from None
                else:
                    piece = await self.inner.read(want)
                if piece:
                    self._follow(piece)
                    pieces.append(piece)
                    got += len(piece)
                if len(piece) < want:  # the stream ended (a WebSocket closed): return what there is
                    break
        finally:
            if budget is not None:
                budget.give(charged)
        return pieces[0] if len(pieces) == 1 else b"".join(pieces)

    def _follow(self, data: bytes) -> None:
        i, size = 0, len(data)
        while i < size:
            if self._state == self._BODY:
                take = min(self._left, size - i)
                if self._topic is not None:
                    self._collect_topic(data[i:i + take])
                elif self._connect is not None:
                    self._collect_protocol(data[i:i + take])
                self._left -= take
                i += take
                if self._left == 0:
                    self._state, self._topic = self._TYPE, None
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
        check_size(self._type, self._length, self.limit_for(self._type), self.describe)
        self._left = self._length
        self._state = self._BODY if self._length else self._TYPE
        self._topic = bytearray() if self._type == PUBLISH and self._length else None
        self._connect = bytearray() if self._type == CONNECT and self._length else None
        if self._type == PUBLISH:
            self._published += 1

    def _collect_protocol(self, chunk: bytes) -> None:
        """A CONNECT starts with its protocol name (2-byte length, then the name) and level: refuse any level but
        MQTT 3.1.1's at once (MQTT-3.1.2-2), before amqtt reads the rest as 3.1.1."""
        head = self._connect
        assert head is not None
        head += chunk[:MAX_PROTOCOL_HEAD - len(head)]
        if len(head) < 2:
            return
        need = 2 + int.from_bytes(head[:2], "big") + 1
        if need > MAX_PROTOCOL_HEAD:  # no protocol name is that long: amqtt refuses the name
            self._connect = None
            return
        if len(head) < need:
            return
        self._connect = None
        level = head[need - 1]
        if level != MQTT_311:
            log.warning("refused %s: %s", self.describe(), UnsupportedProtocol(level))
            raise UnsupportedProtocol(level)

    def _collect_topic(self, chunk: bytes) -> None:
        topic = self._topic
        assert topic is not None
        need = 2 + (int.from_bytes(topic[:2], "big") if len(topic) >= 2 else 65535)
        topic += chunk[:max(0, need - len(topic))]
        if len(topic) >= 2:
            need = 2 + int.from_bytes(topic[:2], "big")
        if len(topic) < need:
            return
        self._topic = None
        check_topic_name(bytes(topic[2:need]), self.describe)


def check_size(packet_type: int, length: int, limit: int, describe: Callable[[], str]) -> None:
    """Refuse a packet whose fixed header announces more than its type may carry (``limit``; 0: no limit)."""
    if limit and length > limit:
        name = PACKET_NAMES.get(packet_type, f"type {packet_type}")
        log.warning("closing %s: %s of %d bytes announced, limit %d", describe(), name, length, limit)
        raise PacketTooLarge(f"{name} of {length} bytes > {limit}")


def check_topic_name(name: bytes, describe: Callable[[], str]) -> None:
    """Refuse a PUBLISH topic with a wildcard or U+0000 (MQTT-3.3.2-2, MQTT-1.5.3-2)."""
    for bad, why in ((b"+", "a wildcard"), (b"#", "a wildcard"), (b"\0", "U+0000")):
        if bad in name:
            log.warning("closing %s: PUBLISH topic %r contains %s", describe(), name[:200], why)
            raise BadTopic(f"PUBLISH topic contains {why}")


class SafeWebSocketsReader(WebSocketsReader):
    """amqtt's WebSocket reader, except that a closed connection ends the read (no busy loop)."""

    _stream: io.BytesIO  # set by amqtt's WebSocketsReader (untyped)

    async def _feed_buffer(self, n: int = 1) -> None:
        buffer = bytearray(self._stream.read())
        while len(buffer) < n:
            try:
                message = await self._protocol.recv()
            except ConnectionClosed:
                break
            buffer.extend(message.encode("utf-8") if isinstance(message, str) else message)
        self._stream = io.BytesIO(buffer)
