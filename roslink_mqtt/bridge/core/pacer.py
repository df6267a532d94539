"""Writes of one connection at a rate: a token bucket under paho's socket writes. I/O-free but for the wrapper.

Why: behind a hop that acknowledges at once, whatever the robot writes leaves its socket at once and waits in a
queue the robot cannot see, ahead of every other connection's bytes. The uplink hands a state or bulk lane one
message at a time, but one message may be a 4 MB map or a 68 kB camera frame: written in one go, it is seconds of
a thin link's queue, and every keep-alive behind it expires. So while the path steers, a paced lane's bytes leave
at its allowance, and the rest of a large message waits in paho, where the uplink counts it as not sent.

The kernel can pace a socket too (``SO_MAX_PACING_RATE``), but in bursts of two segments: on loopback (the bench,
the tests) a segment is 64 kB, so it fed a hidden 1 Mbit/s queue half a second at a time, and the path meter cut
the rate for each. This bucket's bursts are BURST_TIME of the rate (at least MIN_BURST bytes), on any link.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

BURST_TIME = 0.02  # s of the rate a lane may write at once
MIN_BURST = 1_500  # bytes: a burst is never smaller than one packet's worth
SLEEP_MAX = 0.02  # s paho's thread may wait for tokens in one write (it reads between writes)
ZERO_COPY_FROM = 16_384  # bytes: a packet this large is queued as a view (paho copies the rest at every write)


class Pacer:
    """A token bucket: ``rate`` bytes/s (None: unpaced, every write goes through at once)."""

    def __init__(self) -> None:
        self.rate: float | None = None
        self._tokens = 0.0
        self._at: float | None = None

    def burst(self) -> float:
        return max(float(MIN_BURST), (self.rate or 0.0) * BURST_TIME)

    def grant(self, wanted: int, now: float) -> tuple[int, float]:
        """Bytes of ``wanted`` that may be written now, and if none, the seconds until some may."""
        rate = self.rate
        if rate is None:
            self._at = None
            return wanted, 0.0
        if self._at is None:
            self._tokens = self.burst()
        else:
            self._tokens = min(self.burst(), self._tokens + rate * max(0.0, now - self._at))
        self._at = now
        allowed = min(wanted, int(self._tokens))
        if allowed <= 0:
            return 0, (1.0 - self._tokens) / rate if rate > 0 else SLEEP_MAX
        self._tokens -= allowed
        return allowed, 0.0

    def refund(self, unused: int) -> None:
        """The socket took ``unused`` bytes fewer than granted."""
        if unused > 0 and self.rate is not None:
            self._tokens = min(self.burst(), self._tokens + unused)


def paced_send(pacer: Pacer, send: Callable[[bytes | bytearray], int],
               sleep: Callable[[float], None] = time.sleep,
               clock: Callable[[], float] = time.monotonic) -> Callable[[bytes | bytearray], int]:
    """A replacement for paho's ``_sock_send`` (paho's own thread calls it): writes what ``pacer`` grants; with no
    tokens, waits up to SLEEP_MAX once, then raises BlockingIOError as a full socket would (paho keeps the rest of
    the packet and writes it on its next turn, after reading what arrived)."""

    def write(buf: bytes | bytearray) -> int:
        for attempt in (0, 1):
            allowed, wait = pacer.grant(len(buf), clock())
            if allowed:
                try:
                    sent = send(buf[:allowed] if allowed < len(buf) else buf)
                except BlockingIOError:
                    pacer.refund(allowed)  # the socket is full: nothing left, the tokens are not spent
                    raise
                pacer.refund(allowed - sent)
                return sent
            if attempt == 0:
                sleep(min(wait, SLEEP_MAX))
        raise BlockingIOError

    return write


def zero_copy_queue(queue: Callable[..., Any]) -> Callable[..., Any]:
    """A replacement for paho's ``_packet_queue`` that stores a large packet as a ``memoryview``.

    Why: paho writes the rest of its head packet as ``packet[pos:]`` at every attempt, a copy of the whole rest.
    Paced, a 4 MB map is written a burst at a time, 50 attempts a second for the half minute it takes to cross
    a 1 Mbit/s link: 200 MB/s of copies (a new 4 MB allocation each, page faults and the GIL held through each),
    which took so much of the bridge's time that its poses, scans and emergency stops were late while a map was
    under way (bench/weak_link.py, the camera + map rows). A slice of a memoryview copies nothing; sockets, TLS
    and paho's WebSocket wrapper all take one."""

    def packet_queue(command: int, packet: bytes | bytearray, mid: int, qos: int, info: Any = None) -> Any:
        return queue(command, memoryview(packet) if len(packet) >= ZERO_COPY_FROM else packet, mid, qos, info)

    return packet_queue


def install(client: Any, pacer: Pacer) -> None:
    """Pace ``client``'s (a paho client's) socket writes by ``pacer`` (paho 2.2's ``_sock_send``; pinned), and
    keep its large packets as views, so that writing them a burst at a time copies nothing (``_packet_queue``)."""
    client._sock_send = paced_send(pacer, client._sock_send)
    client._packet_queue = zero_copy_queue(client._packet_queue)
