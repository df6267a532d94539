"""One connection's packets read and handled in order on its own task, without a Task or a queue per packet.

amqtt 0.12.1's reader loop costs, for every PUBLISH a client sends: a Task for the keep-alive timeout of the header
read (``wait_for`` on Python 3.11), six or more awaited reads field by field, a Task for ``handle_publish``, a queue
to the broker's client loop, a Task there for the next message and an ``asyncio.wait`` over four futures, then a
second queue to the broadcast loop. At a fleet's rates that was most of the broker's time per message (issue 48:
200 robots, 58 % delivered, 10 s late).

:class:`InlineReader` reads what the socket has (one read, however many packets), cuts it into frames
(:class:`~.frames.FrameParser`) and handles each in order before reading on: a PUBLISH is checked and fanned out to
its subscribers by the broker right here (:meth:`Port.receive_publish`), a SUBSCRIBE or UNSUBSCRIBE is in force
before the next packet of the same connection is looked at (a client that subscribes and publishes in one write
gets its own message), acknowledgements complete their deliveries. QoS 2 from the client is stored at PUBLISH and
delivered at PUBREL (MQTT 3.1.1 §4.3.3, method B), held in the session so a reconnect completes it.

The packet gate's defences hold: sizes from the fixed header and PUBLISH topics (the parser uses the gate's own
checks), pacing of user logins (:class:`~.guard.Pacer`), and the per-login budget and piece timeout of large packets
still arriving (:class:`~.guard.PartialBudget`, fix 29). Only for TCP and TLS connections; WebSocket connections keep
amqtt's reader.
"""

from __future__ import annotations

import asyncio
import logging
import sys
import time
from collections.abc import Awaitable
from typing import Any, Protocol

from amqtt.adapters import StreamReaderAdapter
from amqtt.mqtt import packet_class
from amqtt.mqtt.disconnect import DisconnectPacket
from amqtt.mqtt.packet import MQTTFixedHeader
from amqtt.mqtt.puback import PubackPacket
from amqtt.mqtt.pubcomp import PubcompPacket
from amqtt.mqtt.pubrec import PubrecPacket
from amqtt.mqtt.subscribe import SubscribePacket
from amqtt.mqtt.unsubscribe import UnsubscribePacket

from .frames import Frame, FrameParser, Malformed, Publish, read_publish
from .guard import READ_CHUNK, PacketGate, PacketRefused, PacketStalled

log = logging.getLogger("roslink_mqtt.broker")

READ_SIZE = READ_CHUNK  # bytes asked of the socket per read: any number of packets, or a piece of a large one
ATTR_QOS2_IN = "roslink.qos2_in"  # Session.attributes: packet id -> Publish received at QoS 2, awaiting its PUBREL
MAX_QOS2_IN = 1000  # QoS 2 messages one session may hold between PUBLISH and PUBREL (more: the oldest goes)

PUBLISH, PUBACK, PUBREC, PUBREL, PUBCOMP, SUBSCRIBE, UNSUBSCRIBE, PINGREQ, DISCONNECT = 3, 4, 5, 6, 7, 8, 10, 12, 14
CONNECT = 1


class Port(Protocol):
    """What the reader asks of the broker (hardened.HardenedBroker)."""

    def receive_publish(self, session: Any, handler: Any, publish: Publish) -> Awaitable[None]: ...

    def receive_subscription(self, session: Any, handler: Any, request: Any) -> Awaitable[None]: ...


def usable(reader: Any) -> bool:
    """The connection's reader is the packet gate over a plain stream (TCP or TLS): the inline reader can read it."""
    return isinstance(reader, PacketGate) and isinstance(reader.inner, StreamReaderAdapter)


def _timeout(seconds: float | None) -> Any:
    """A deadline without a Task (asyncio.timeout, Python 3.11+); on 3.10 the caller uses wait_for."""
    return asyncio.timeout(seconds)  # type: ignore[attr-defined,unused-ignore]


class InlineReader:
    def __init__(self, handler: Any, broker: Port) -> None:
        self.handler, self.broker = handler, broker
        self.session = handler.session
        gate: PacketGate = handler.reader
        self.gate = gate
        self.stream: asyncio.StreamReader = gate.inner._reader  # type: ignore[attr-defined,unused-ignore]
        self.parser = FrameParser(gate.limit_for, lambda: gate.describe())
        self._charged = 0  # bytes of a large packet still arriving charged to the login's budget

    async def run(self) -> None:
        """Read until the connection ends; then as amqtt's loop does: report the close, stop the handler."""
        handler = self.handler
        handler._reader_ready.set()
        await handler.started.wait()  # amqtt's start() finishes first: its resends, its disconnect waiter
        keep_alive = self.session.keep_alive if self.session.keep_alive and self.session.keep_alive > 0 else None
        try:
            while True:
                data = await self._read(keep_alive)
                if not data:
                    break
                frames = self.parser.feed(data)
                self._charge()
                pacer = self.gate.pacer
                for frame in frames:
                    if pacer is not None and frame.kind == PUBLISH:
                        # fix 23: a paced login's PUBLISH spends its allowance; over it, this connection's next
                        # packet waits (and nothing more is read), however many one read brought
                        wait = pacer.wait_for(1, time.monotonic())
                        if wait > 0:
                            await asyncio.sleep(wait)
                    await self._handle(frame)
        except (TimeoutError, asyncio.TimeoutError):
            handler.handle_read_timeout()
        except Malformed as malformed:  # MQTT-4.8.0-1: the stream is mid-packet; the connection is closed below
            log.warning("closing %s: %s", self.gate.describe(), malformed)
        except PacketRefused:  # logged where it was found (the gate's checks); the connection is closed below
            pass
        except asyncio.CancelledError:
            pass
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        except Exception as error:  # noqa: BLE001 - as amqtt's loop: one connection's error ends that connection
            log.warning("inline reader of %s: unexpected %r; closing the connection", self.gate.describe(), error)
        finally:
            self._release()
        await handler.handle_connection_closed()
        handler._reader_stopped.set()
        await handler.stop()

    async def _read(self, keep_alive: float | None) -> bytes:
        large = self.parser.announced > READ_CHUNK
        timeout = keep_alive
        if large and self.gate.piece_timeout > 0:
            timeout = self.gate.piece_timeout if timeout is None else min(timeout, self.gate.piece_timeout)
        try:
            if sys.version_info >= (3, 11):
                async with _timeout(timeout):
                    return await self.stream.read(READ_SIZE)
            return await asyncio.wait_for(self.stream.read(READ_SIZE), timeout)
        except (TimeoutError, asyncio.TimeoutError):
            if large and self.gate.piece_timeout > 0 and (keep_alive is None or self.gate.piece_timeout < keep_alive):
                why = (f"the rest of a {self.parser.announced}-byte packet did not arrive within "
                       f"{self.gate.piece_timeout:g} s ({self.parser.held} bytes arrived)")
                log.warning("closing %s: %s", self.gate.describe(), why)
                raise PacketStalled(why) from None
            raise

    def _charge(self) -> None:
        """Fix 29: the bytes of a large packet still arriving count against the login's budget."""
        budget = self.gate.budget
        if budget is None:
            return
        want = self.parser.held if self.parser.announced > READ_CHUNK else 0
        if want > self._charged:
            if not budget.take(want - self._charged):
                why = (f"packets still arriving on this login's connections hold {budget.held} bytes, "
                       f"limit {budget.limit}")
                log.warning("closing %s: %s", self.gate.describe(), why)
                raise PacketStalled(why)
        elif want < self._charged:
            budget.give(self._charged - want)
        self._charged = want

    def _release(self) -> None:
        if self._charged and self.gate.budget is not None:
            self.gate.budget.give(self._charged)
        self._charged = 0

    async def _acknowledge(self, kind: Any, head: bytes, packet_id: int | None) -> None:
        """PUBACK, PUBREC or PUBCOMP (``kind``, amqtt's class): written at once on a TCP/TLS transport, else through
        amqtt's send."""
        pid = packet_id or 0
        if not self.handler.write_now(head + pid.to_bytes(2, "big")):
            await self.handler._send_packet(kind.build(pid))

    async def _handle(self, frame: Frame) -> None:
        kind, handler, session = frame.kind, self.handler, self.session
        if kind == PUBLISH:
            publish = read_publish(frame.flags, frame.body)
            if publish.qos == 0:
                await self.broker.receive_publish(session, handler, publish)
            elif publish.qos == 1:
                await self.broker.receive_publish(session, handler, publish)
                await self._acknowledge(PubackPacket, b"\x40\x02", publish.packet_id)
            else:
                pid = publish.packet_id or 0
                held: dict[int, Publish] = session.attributes.setdefault(ATTR_QOS2_IN, {})
                if pid not in held and len(held) >= MAX_QOS2_IN:
                    held.pop(next(iter(held)))
                held[pid] = publish  # a resent PUBLISH (DUP) replaces it: delivered once, at PUBREL
                await self._acknowledge(PubrecPacket, b"\x50\x02", pid)
        elif kind == PUBREL:
            pid = _packet_id(frame)
            waiting: dict[int, Publish] = session.attributes.get(ATTR_QOS2_IN) or {}
            released = waiting.pop(pid, None)
            if released is not None:
                await self.broker.receive_publish(session, handler, released)
            await self._acknowledge(PubcompPacket, b"\x70\x02", pid)
        elif kind == PUBACK:
            await handler.handle_puback(PubackPacket.build(_packet_id(frame)))
        elif kind == PUBREC:
            await handler.handle_pubrec(PubrecPacket.build(_packet_id(frame)))
        elif kind == PUBCOMP:
            await handler.handle_pubcomp(PubcompPacket.build(_packet_id(frame)))
        elif kind == PINGREQ:
            await handler.handle_pingreq(None)
        elif kind in (SUBSCRIBE, UNSUBSCRIBE):
            packet = await _decode(frame)
            assert isinstance(packet, (SubscribePacket, UnsubscribePacket))
            if packet.variable_header is None or packet.payload is None:
                raise Malformed("a SUBSCRIBE or UNSUBSCRIBE without its packet id or filters")
            request = _request(packet)
            await self.broker.receive_subscription(session, handler, request)
        elif kind == DISCONNECT:
            await handler.handle_disconnect(DisconnectPacket())
        elif kind == CONNECT:
            await handler.handle_connect(None)  # MQTT-3.1.0-2: a second CONNECT ends the connection
        else:
            raise Malformed(f"a packet of type {kind}, which a client never sends (MQTT-4.8.0-1)")


def _packet_id(frame: Frame) -> int:
    if len(frame.body) != 2:
        raise Malformed(f"a packet of type {frame.kind} with {len(frame.body)} bytes where its packet id is 2")
    return int.from_bytes(frame.body, "big")


def _request(packet: SubscribePacket | UnsubscribePacket) -> Any:
    from amqtt.mqtt.protocol.broker_handler import Subscription, UnSubscription

    assert packet.variable_header is not None and packet.payload is not None
    if isinstance(packet, SubscribePacket):
        return Subscription(packet.variable_header.packet_id, packet.payload.topics)
    return UnSubscription(packet.variable_header.packet_id, packet.payload.topics)


class _Bytes:
    """One frame's body as the stream amqtt's decoders read field by field (rare packets only)."""

    def __init__(self, data: bytes) -> None:
        self.data, self.at = data, 0

    async def read(self, n: int = -1) -> bytes:
        end = len(self.data) if n < 0 else self.at + n
        out, self.at = self.data[self.at:end], min(end, len(self.data))
        return out


async def _decode(frame: Frame) -> Any:
    header = MQTTFixedHeader(frame.kind, frame.flags, len(frame.body))
    try:
        return await packet_class(header).from_stream(_Bytes(frame.body), fixed_header=header)  # type: ignore[arg-type,unused-ignore]
    except Exception as error:  # noqa: BLE001 - any decoding failure is a malformed packet
        raise Malformed(f"a malformed packet of type {frame.kind}: {error}") from None

