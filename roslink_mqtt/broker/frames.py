"""MQTT 3.1.1 frames cut from a byte stream in one pass, without an ``await`` per field.

amqtt 0.12.1 reads every packet field by field from the stream (the type byte, each byte of the remaining length,
the topic's length, the topic, the packet id, the payload): six or more awaited reads per PUBLISH, each through the
adapters and the packet gate, plus a Task for the keep-alive timeout on every packet. At a fleet's rates that was a
large share of the broker's time per message. :class:`FrameParser` takes whatever the socket gave (several packets, or
part of one) and returns the complete frames in it; :func:`read_publish` splits a PUBLISH body in place.

The checks of :class:`~.guard.PacketGate` hold here too, from the same functions: a frame that announces more than its
type may carry is refused from its fixed header (before its body is held), a PUBLISH topic with a wildcard or U+0000
ends the connection. Pure: no I/O, no clock.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from .guard import PUBLISH, PacketRefused, check_size, check_topic_name

MAX_LENGTH_BYTES = 4  # MQTT-2.2.3: the remaining length takes one to four bytes


class Malformed(PacketRefused):
    """A frame that cannot be MQTT 3.1.1 (MQTT-4.8.0-1: the connection is closed)."""


class Frame(NamedTuple):
    kind: int  # the packet type, 1..15
    flags: int  # the fixed header's low four bits
    body: bytes  # the remaining length's bytes: variable header and payload


class Publish(NamedTuple):
    topic: str
    qos: int
    retain: bool
    dup: bool
    packet_id: int | None  # QoS 1 and 2 only
    payload: bytes


class FrameParser:
    """Complete frames out of the bytes fed so far; what is left over waits for the next :meth:`feed`.

    ``limit_for(packet_type)`` is the largest remaining length accepted for a type (0: no limit), as for
    :class:`~.guard.PacketGate`; ``describe`` names the connection in the log line of a refusal.
    """

    __slots__ = ("_buffer", "_limit_for", "_describe", "_announced")

    def __init__(self, limit_for: Callable[[int], int], describe: Callable[[], str]) -> None:
        self._buffer = bytearray()
        self._limit_for, self._describe = limit_for, describe
        self._announced = 0  # the whole size of the incomplete frame at the front, once its header is in (else 0)

    @property
    def held(self) -> int:
        """Bytes of an incomplete frame held until the rest arrives."""
        return len(self._buffer)

    @property
    def announced(self) -> int:
        """The size of the incomplete frame being collected (fixed header included), 0 while its header is not
        complete or nothing is held."""
        return self._announced

    def feed(self, data: bytes) -> list[Frame]:
        """The frames that ``data`` completes, in order. Raises :class:`~.guard.PacketRefused` (the connection must
        be closed) for a frame over its type's limit, a malformed remaining length or a bad PUBLISH topic."""
        buffer = self._buffer
        buffer += data
        frames: list[Frame] = []
        size, at = len(buffer), 0
        self._announced = 0
        while size - at >= 2:
            first = buffer[at]
            length, shift, i = 0, 0, at + 1
            while True:
                if i >= size:
                    break
                byte = buffer[i]
                i += 1
                length |= (byte & 0x7F) << shift
                if not byte & 0x80:
                    shift = -1  # complete
                    break
                shift += 7
                if shift >= 7 * MAX_LENGTH_BYTES:
                    raise Malformed("a remaining length of more than four bytes (MQTT-2.2.3)")
            if shift != -1:
                break  # the remaining length is not complete yet
            kind = first >> 4
            check_size(kind, length, self._limit_for(kind), self._describe)
            end = i + length
            if end > size:
                self._announced = end - at
                break
            body = bytes(buffer[i:end])
            if kind == PUBLISH:
                _check_publish_topic(body, self._describe)
            frames.append(Frame(kind, first & 0x0F, body))
            at = end
        if at:
            del buffer[:at]
        return frames


def _check_publish_topic(body: bytes, describe: Callable[[], str]) -> None:
    if len(body) < 2 or len(body) < 2 + int.from_bytes(body[:2], "big"):
        raise Malformed("a PUBLISH shorter than its topic")
    check_topic_name(body[2:2 + int.from_bytes(body[:2], "big")], describe)


def read_publish(flags: int, body: bytes) -> Publish:
    """A PUBLISH frame's fields (its topic already checked by :meth:`FrameParser.feed`)."""
    qos = (flags >> 1) & 0x03
    if qos == 3:
        raise Malformed("a PUBLISH with QoS 3 (MQTT-3.3.1-4)")
    end = 2 + int.from_bytes(body[:2], "big")
    try:
        topic = body[2:end].decode("utf-8")
    except UnicodeDecodeError:
        raise Malformed("a PUBLISH topic that is not UTF-8 (MQTT-1.5.3-1)") from None
    packet_id = None
    if qos:
        if len(body) < end + 2:
            raise Malformed("a PUBLISH without its packet identifier")
        packet_id = int.from_bytes(body[end:end + 2], "big")
        end += 2
    return Publish(topic, qos, bool(flags & 0x01), bool(flags & 0x08), packet_id, body[end:])
