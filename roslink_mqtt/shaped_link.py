"""A TCP proxy that makes a loopback connection behave like a long, uneven, thin Internet link.

    python -m roslink_mqtt.shaped_link --listen 127.0.0.1:18830 --to 127.0.0.1:1883 \
        --delay-ms 60 --jitter-ms 20 --loss 0.01 --up-kbit 256 --down-kbit 1024
    python -m roslink_mqtt.shaped_link ... --hidden-queue --phases "10:1024,10:128,4:0,10:256"

Why it exists: this machine's kernel has no ``netem``, yet the benchmarks (bench/spiral.py) and anyone
trying a robot "over the cloud" need a link with delay, jitter and loss between the bridge and the
broker. Point the bridge's ``--url`` at the proxy's port instead of the broker's.

What it does to each direction of every connection, independently:

* **delay**: every chunk read is written ``delay ± jitter`` ms later (normal distribution, never
  negative, so the mean one-way delay is ``delay``);
* **order**: TCP never reorders, so a chunk is never written before the one read ahead of it (a late
  chunk holds up the ones behind it, as on a real link);
* **loss**: TCP never loses data either; a lost segment is retransmitted after the sender's
  retransmission timeout, so with probability ``loss`` a chunk is held back an extra ``--rto-ms``
  (200 ms, Linux's minimum RTO) and everything behind it with it.

**Bandwidth** (``--up-kbit``, ``--down-kbit``; up = client to target, the robot's uplink when the bridge is the
client): one link per direction, shared by every connection through the proxy. It carries one packet at a time,
in the order the packets arrived from any connection (a FIFO), each taking ``size / rate`` of link time; the
delay, jitter and loss above start when a packet has left the link (they model the path behind the bottleneck).
Where the link's queue lives is the choice between two models, because a sender that steers by its own socket
sees one and not the other:

* **visible queue** (the default; a cellular modem or router whose queue backs up into the robot): a
  connection's next packet is read only once its previous one is on the link, so what the link cannot carry yet
  waits in the *sender's* socket, where the sender sees it (``SIOCOUTQ``) as it would see a real modem's queue
  (unacknowledged bytes); the proxy's own receive buffers are kept small (``RCVBUF``) so that little waits unseen.
* **hidden queue** (``--hidden-queue``; a split-TCP performance-enhancing proxy, a VPN concentrator, a TLS or
  WebSocket load balancer: a hop that acknowledges the sender's bytes at once): the proxy reads everything every
  connection sends as soon as it arrives, so the sender's ``SIOCOUTQ`` stays near zero, and the bytes wait in ONE
  FIFO per direction shared by every connection, in arrival order, drained at the link's rate: the sender sees
  an empty socket while seconds of its data wait behind the bottleneck. The FIFO is bounded (``--queue-kb``;
  default :data:`HIDDEN_QUEUE_SECONDS` of the direction's highest rate, at least :data:`HIDDEN_QUEUE_MIN` bytes):
  at the bound the hop stops reading, as a real one does when its buffer is full, so from then on backpressure
  returns to the senders' sockets, once the hop's own kernel buffer (:data:`HIDDEN_RCVBUF`) and a little
  read-ahead have filled too (together ~60 kB more than the bound stay hidden: 56 kB measured on loopback).

**Capacity that changes** (``--phases`` for the uplink, ``--down-phases`` for the downlink): a list of
``seconds:kbit/s`` phases, e.g. ``"10:1024,10:128,4:0,10:256"``, started when the proxy starts listening and
repeated until it stops (``--phases-once``: played once, then the last phase's rate stays). A rate of 0 is a dead
spot: nothing crosses that direction, yet every connection stays open (a vehicle in a tunnel, not a reset); with
the visible model the senders' sockets fill, with the hidden one the hop's FIFO does. Packets already on the link
when the rate changes finish at the new rate. From Python, :meth:`ShapedLink.set_rate` changes a direction's rate
at a given moment, from any thread.

Chunks are what one ``read`` returned (up to 64 KiB; one packet of at most ``packet_size`` on a rate-limited
link), not IP packets: a good model for small MQTT messages, a coarse one for large transfers.
Both sockets get TCP_NODELAY so the proxy adds no Nagle
stall of its own. Pure asyncio, no ROS, no MQTT: it shapes any TCP service.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import random
import socket
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

CHUNK = 65536
QUEUED_CHUNKS = 1024  # per direction: a reader this far ahead of the writer waits (bounded memory)
MTU_PAYLOAD = 1448  # bytes of one full TCP segment on an Ethernet-sized path: the unit a thin link carries
RCVBUF = 1024  # SO_RCVBUF of the proxy's sockets on a rate-limited link (the kernel doubles it, to ~2 KiB)
# The MSS the proxy announces where its window is that small: a sender's segment is at most half the largest window
# it saw (~576 B here), and a window of fewer bytes than a segment opens nothing: TCP then waits for its persist
# timer (200 ms, doubling) and sends one window's worth per probe. Seen as a lane stuck at ~1.2 kB/s with 3 kB in
# its socket (ss: rwnd_limited 100 %, timer persist, snd_wnd 489 < mss 576), while the link was half idle: a
# stall of the model, not of a modem. Segments of this size fit any window the proxy opens.
SMALL_MSS = 256
READ_AHEAD = 512  # asyncio's reader pauses its socket beyond twice this: little read ahead of the wire, unseen
# The hidden-queue hop: its receive buffers are large enough that a sender on loopback never waits for the hop's
# reads, yet bounded (the kernel doubles it, to 32 KiB, and autotuning is off), so that once the FIFO is full
# and the hop stops reading, the sender's socket fills soon after, as behind a real hop with a full buffer.
HIDDEN_RCVBUF = 16384
HIDDEN_READ_AHEAD = 8192  # asyncio's reader pauses its socket beyond twice this while the hop does not read
HIDDEN_QUEUE_SECONDS = 10.0  # default bound of a hidden FIFO, in seconds of the direction's highest rate
HIDDEN_QUEUE_MIN = 65536  # ... and at least this many bytes
_EPSILON = 1e-6  # bytes: float rounding in the link's byte clock

Phases = tuple[tuple[float, float], ...]
"""A capacity schedule: ``(seconds, bytes per second)`` per phase; a rate of 0 is a dead spot."""


@dataclass(frozen=True, slots=True)
class Shape:
    """One direction's delay model; all times in seconds."""

    delay: float = 0.0
    jitter: float = 0.0
    loss: float = 0.0
    rto: float = 0.2

    def __post_init__(self) -> None:
        if self.delay < 0 or self.jitter < 0 or self.rto < 0:
            raise ValueError("delay, jitter and rto must not be negative")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError("loss is a probability in [0, 1)")


class Schedule:
    """When each chunk of one direction may be written: delay, jitter and loss, never out of order."""

    def __init__(self, shape: Shape, rng: random.Random) -> None:
        self.shape, self.rng = shape, rng
        self.last = 0.0  # release time of the previous chunk

    def release_time(self, now: float, share: float = 1.0) -> float:
        """The moment a chunk read at ``now`` may be written; ``share``: the part of one of the link's packets the
        chunk is (a rate-limited link loses ``loss`` of its packets, however the sender cut them into segments)."""
        shape = self.shape
        delay = max(0.0, self.rng.gauss(shape.delay, shape.jitter)) if shape.jitter else shape.delay
        if shape.loss and self.rng.random() < shape.loss * min(1.0, share):
            delay += shape.rto  # the segment was lost and sent again after the retransmission timeout
        self.last = max(self.last, now + delay)
        return self.last


def _wake(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


class Wire:
    """One direction of a rate-limited link, shared by every connection: a FIFO of packets, one at a time.

    The link keeps a byte clock: :meth:`capacity` is how many bytes it could have carried since it first
    served, the integral of its rate, so a rate that changes (:meth:`set_rate`, 0 for a dead spot) moves every
    packet still waiting, with no reordering and no lock (one event loop). :meth:`book` places ``size`` bytes
    after everything booked before (arrival order) and returns the byte position of its last byte; the packet
    has left once the byte clock passes it (:meth:`wait_sent`). :meth:`queued` is what is booked and has not
    left: the FIFO. At a constant rate this is exactly ``start = max(now, free_at); free_at = start + size/rate``.

    ``limit`` (the hidden-queue model only): bytes the hop may hold (read and not yet written out) before its
    readers stop reading (:meth:`room`), so the queue hides at most that much.
    """

    def __init__(self, rate: float, *, limit: int | None = None) -> None:
        if rate <= 0:
            raise ValueError("a link's rate is a positive number of bytes per second")
        if limit is not None and limit < 1:
            raise ValueError("a hidden queue's bound is a positive number of bytes")
        self.rate = rate
        self.limit = limit
        self.carried = 0  # bytes booked, for tests and the final report
        self.held = 0  # bytes the hidden hop has read and not yet written out
        self._t0: float | None = None  # start of the current rate segment (set on first use)
        self._c0 = 0.0  # the byte clock at _t0
        self._booked = 0.0  # byte position of the last byte booked so far
        self._sent_waiters: set[asyncio.Future[None]] = set()
        self._room_waiters: set[asyncio.Future[None]] = set()

    @property
    def packet_size(self) -> int:
        """Bytes read and booked at once: a TCP segment on thin links, more on fast ones (≈1 ms of link time)."""
        return max(MTU_PAYLOAD, min(CHUNK, int(self.rate / 1000)))

    def _start(self, now: float) -> None:
        if self._t0 is None:
            self._t0 = now

    def capacity(self, now: float) -> float:
        """Bytes the link could have carried from its first use until ``now``."""
        self._start(now)
        assert self._t0 is not None
        return self._c0 + self.rate * max(0.0, now - self._t0)

    def set_rate(self, rate: float, now: float) -> None:
        """From ``now`` on the link carries ``rate`` bytes/s (0: a dead spot); waiting packets follow at once."""
        if rate < 0:
            raise ValueError("a link's rate must not be negative")
        if self._t0 is not None:
            self._c0, self._t0 = self.capacity(now), max(now, self._t0)
        self.rate = rate
        for future in self._sent_waiters:
            _wake(future)  # each recomputes its departure at the new rate

    def book(self, size: int, now: float) -> float:
        """Place ``size`` bytes on the link after everything booked before; the byte position of their end."""
        self._booked = max(self.capacity(now), self._booked) + size
        self.carried += size
        return self._booked

    def departure(self, end: float) -> float:
        """When the byte at position ``end`` leaves the link at the current rate (inf in a dead spot)."""
        assert self._t0 is not None, "book before asking for a departure"
        if end <= self._c0:
            return self._t0  # it left before the current rate began
        return self._t0 + (end - self._c0) / self.rate if self.rate > 0 else float("inf")

    def reserve(self, size: int, now: float) -> float:
        """Book ``size`` bytes and return the moment their last byte has left, at the current rate."""
        return self.departure(self.book(size, now))

    def queued(self, now: float) -> int:
        """Bytes booked that have not left the link yet: the FIFO's length."""
        return max(0, round(self._booked - self.capacity(now)))

    async def wait_sent(self, end: float) -> float:
        """Wait until the byte at position ``end`` has left, however the rate changes meanwhile; its departure."""
        loop = asyncio.get_running_loop()
        while True:
            waiting = end - self.capacity(loop.time())
            if waiting <= _EPSILON:
                return self.departure(end)
            future: asyncio.Future[None] = loop.create_future()
            self._sent_waiters.add(future)
            timer = loop.call_later(waiting / self.rate, _wake, future) if self.rate > 0 else None
            try:
                await future
            finally:
                self._sent_waiters.discard(future)
                if timer is not None:
                    timer.cancel()

    def room_left(self) -> int:
        """Bytes the hidden hop may still read before it stops (unbounded: a chunk)."""
        return CHUNK if self.limit is None else max(0, self.limit - self.held)

    async def room(self) -> None:
        """Wait until the hidden hop may read another packet: what it holds is below its bound."""
        loop = asyncio.get_running_loop()
        while self.room_left() < min(self.packet_size, self.limit or CHUNK):
            future: asyncio.Future[None] = loop.create_future()
            self._room_waiters.add(future)
            try:
                await future
            finally:
                self._room_waiters.discard(future)

    def release(self, size: int) -> None:
        """The hidden hop has written ``size`` bytes out (or dropped them with their connection)."""
        self.held -= size
        for future in self._room_waiters:
            _wake(future)


def _nodelay(writer: asyncio.StreamWriter) -> None:
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, schedule: Schedule,
                wire: Wire | None = None, hidden: bool = False) -> None:
    """Copy one direction through the wire (if rate-limited) and the schedule; end (and half-close) with the reader.

    Visible queue (or no rate limit): one task reads a packet, waits until the link has carried it and only then
    reads the next, so the backlog stays in the sender's socket. Hidden queue: one task reads whatever arrives and
    books it on the shared link at once (the FIFO), another hands each packet on when the link has carried it.
    """
    await _Direction(reader, writer, schedule, wire, hidden).run()


class _Direction:
    """One connection's one direction: the tasks of :func:`_pump` and what they share."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, schedule: Schedule,
                 wire: Wire | None, hidden: bool) -> None:
        self.reader, self.writer, self.schedule, self.wire = reader, writer, schedule, wire
        self.hidden = hidden and wire is not None
        self.queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue(QUEUED_CHUNKS)
        self.loop = asyncio.get_running_loop()
        self.held = 0  # bytes of this connection the hidden hop holds: given back to the bound if the connection dies

    async def read(self) -> None:
        wire = self.wire
        try:
            while chunk := await self.reader.read(wire.packet_size if wire is not None else CHUNK):
                sent = self.loop.time()
                if wire is not None:
                    # the next packet of this connection stays in its sender's socket until this one has left
                    sent = await wire.wait_sent(wire.book(len(chunk), sent))
                share = len(chunk) / wire.packet_size if wire is not None else 1.0
                await self.queue.put((self.schedule.release_time(sent, share), chunk))
        except (ConnectionError, OSError):
            pass
        await self.queue.put(None)

    async def take(self, wire: Wire, fifo: asyncio.Queue[tuple[float, bytes] | None]) -> None:
        try:
            while True:
                await wire.room()  # a full hop stops reading: the sender's socket fills from here on
                chunk = await self.reader.read(max(1, min(CHUNK, wire.room_left())))
                if not chunk:
                    break
                now, size = self.loop.time(), wire.packet_size
                for i in range(0, len(chunk), size):
                    packet = chunk[i:i + size]
                    self.held += len(packet)
                    wire.held += len(packet)
                    fifo.put_nowait((wire.book(len(packet), now), packet))
        except (ConnectionError, OSError):
            pass
        fifo.put_nowait(None)

    async def carry(self, wire: Wire, fifo: asyncio.Queue[tuple[float, bytes] | None]) -> None:
        while (item := await fifo.get()) is not None:
            end, packet = item
            sent = await wire.wait_sent(end)
            await self.queue.put((self.schedule.release_time(sent), packet))
        await self.queue.put(None)

    async def write(self) -> None:
        while (item := await self.queue.get()) is not None:
            release, chunk = item
            if (wait := release - self.loop.time()) > 0:
                await asyncio.sleep(wait)
            self.writer.write(chunk)
            if self.hidden and self.wire is not None:
                self.held -= len(chunk)
                self.wire.release(len(chunk))
            await self.writer.drain()
        with contextlib.suppress(OSError):
            self.writer.write_eof()

    async def run(self) -> None:
        wire = self.wire
        if self.hidden and wire is not None:
            fifo: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue()  # bounded by the wire's limit
            tasks = [asyncio.create_task(self.take(wire, fifo)), asyncio.create_task(self.carry(wire, fifo))]
        else:
            tasks = [asyncio.create_task(self.read())]
        try:
            await self.write()
        except (ConnectionError, OSError):
            pass
        finally:
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            if wire is not None and self.held:
                wire.release(self.held)


def _window(sock: socket.socket, hidden: bool) -> None:
    """The receive window of a rate-limited link's socket, set before the handshake: the hidden hop's large one, or
    the visible model's small one with a segment size that fits it (SMALL_MSS)."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, HIDDEN_RCVBUF if hidden else RCVBUF)
    if not hidden:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_MAXSEG, SMALL_MSS)


def peak_rate(rate: float, phases: Phases | None) -> float:
    """The highest rate a direction is configured with (its phases', else its fixed rate)."""
    return max(r for _, r in phases) if phases else rate


def phase_at(phases: Phases, elapsed: float, *, repeat: bool = True) -> tuple[int, float]:
    """(index of the phase in force ``elapsed`` s after the schedule began, seconds until the next change; inf
    when there is none: a schedule played once has reached its last phase, which then stays, or has one phase)."""
    if not phases:
        raise ValueError("a schedule needs at least one phase")
    if len(phases) == 1:
        return 0, float("inf")
    if repeat:
        elapsed %= sum(seconds for seconds, _ in phases)
    for index, (seconds, _) in enumerate(phases[:-1] if not repeat else phases):
        if elapsed < seconds:
            return index, seconds - elapsed
        elapsed -= seconds
    return len(phases) - 1, float("inf") if not repeat else max(0.0, phases[-1][0] - elapsed)


def _check_phases(phases: Phases) -> None:
    if not phases:
        raise ValueError("a schedule needs at least one phase")
    if any(seconds <= 0 or rate < 0 for seconds, rate in phases):
        raise ValueError("each phase lasts a positive number of seconds at a rate that is not negative")
    if not any(rate > 0 for _, rate in phases):
        raise ValueError("a schedule needs at least one phase that carries data")


class ShapedLink:
    """The proxy: one listening socket, every accepted connection forwarded to ``target`` through two schedules.

    ``up_rate`` / ``down_rate``: bytes per second from clients to the target and back (0: unlimited), each one
    :class:`Wire` shared by every connection. ``up_phases`` / ``down_phases``: a :data:`Phases` schedule for that
    direction instead of a fixed rate, started by :meth:`start` and repeated (``repeat_phases=False``: played
    once, the last phase then stays). ``hidden_queue``: the hidden-queue model (see the module's docstring) on
    every rate-limited direction, each FIFO bounded by ``queue_bytes`` (default: :data:`HIDDEN_QUEUE_SECONDS`
    of the direction's highest rate, at least :data:`HIDDEN_QUEUE_MIN`). ``on_rate(direction, bytes_per_s)`` is
    called in the link's event loop at every change of rate (the command line prints them).
    """

    def __init__(self, target: tuple[str, int], shape: Shape, *, seed: int | None = None, up_rate: float = 0.0,
                 down_rate: float = 0.0, hidden_queue: bool = False, queue_bytes: int | None = None,
                 up_phases: Sequence[tuple[float, float]] | None = None,
                 down_phases: Sequence[tuple[float, float]] | None = None, repeat_phases: bool = True,
                 on_rate: Callable[[str, float], None] | None = None) -> None:
        self.target, self.shape = target, shape
        self.rng = random.Random(seed)
        self.connections = 0
        self.hidden_queue = hidden_queue
        self.phases: dict[str, Phases] = {}
        self.repeat_phases = repeat_phases
        self.on_rate = on_rate
        wires: list[Wire | None] = []
        for name, rate, given in (("up", up_rate, up_phases), ("down", down_rate, down_phases)):
            phases = tuple((float(s), float(r)) for s, r in given) if given is not None else None
            if phases is not None:
                _check_phases(phases)
                self.phases[name] = phases
            peak = peak_rate(rate, phases)
            if not peak:
                wires.append(None)
                continue
            limit = None
            if hidden_queue:
                limit = queue_bytes if queue_bytes is not None else max(HIDDEN_QUEUE_MIN,
                                                                         int(HIDDEN_QUEUE_SECONDS * peak))
            wires.append(Wire(peak, limit=limit))
        self.up, self.down = wires
        self._loop: asyncio.AbstractEventLoop | None = None
        self._drivers: list[asyncio.Task[None]] = []

    def set_rate(self, *, up: float | None = None, down: float | None = None) -> None:
        """Change a direction's rate (bytes/s; 0: a dead spot) now; safe from any thread (applied by the link's
        event loop within moments when called from another one). A running phase schedule sets its own rate
        again at its next phase."""
        changes = [(name, wire, rate) for name, wire, rate in (("up", self.up, up), ("down", self.down, down))
                   if rate is not None]
        for name, wire, rate in changes:
            if wire is None:
                raise ValueError(f"the {name} direction is unlimited: give it a rate or phases when building the link")
            if rate < 0:
                raise ValueError("a link's rate must not be negative")

        def apply() -> None:
            assert self._loop is not None
            for name, wire, rate in changes:
                assert wire is not None
                wire.set_rate(rate, self._loop.time())
                if self.on_rate is not None:
                    self.on_rate(name, rate)

        if self._loop is None:  # not started: the rate the link starts with
            for _, wire, rate in changes:
                assert wire is not None
                wire.rate = rate
            return
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is self._loop:
            apply()
        else:
            self._loop.call_soon_threadsafe(apply)

    async def _drive(self, name: str, wire: Wire, phases: Phases) -> None:
        """Play ``phases`` on ``wire``: each rate at its boundary, boundaries counted from the start (no drift)."""
        loop = asyncio.get_running_loop()
        began = loop.time()
        while True:
            index, remaining = phase_at(phases, loop.time() - began, repeat=self.repeat_phases)
            rate = phases[index][1]
            wire.set_rate(rate, loop.time())
            if self.on_rate is not None:
                self.on_rate(name, rate)
            if remaining == float("inf"):
                return
            await asyncio.sleep(remaining + 1e-4)  # just past the boundary: phase_at then names the next phase

    async def _connect_upstream(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        if self.down is None:
            return await asyncio.open_connection(*self.target)
        sock = socket.socket(socket.AF_INET6 if ":" in self.target[0] else socket.AF_INET, socket.SOCK_STREAM)
        try:
            # before connecting: the window the target may fill is set at the handshake
            _window(sock, self.hidden_queue)
            sock.setblocking(False)
            await asyncio.get_running_loop().sock_connect(sock, self.target)
        except OSError:
            sock.close()
            raise
        return await asyncio.open_connection(sock=sock, limit=HIDDEN_READ_AHEAD if self.hidden_queue else READ_AHEAD)

    async def _serve(self, client_reader: asyncio.StreamReader, client_writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        try:
            upstream_reader, upstream_writer = await self._connect_upstream()
        except OSError:
            client_writer.close()  # the far end is down: the client sees a refused/closed connection
            return
        for w in (client_writer, upstream_writer):
            _nodelay(w)
        try:
            await asyncio.gather(
                _pump(client_reader, upstream_writer, Schedule(self.shape, self.rng), self.up, self.hidden_queue),
                _pump(upstream_reader, client_writer, Schedule(self.shape, self.rng), self.down, self.hidden_queue),
            )
        finally:
            for w in (client_writer, upstream_writer):
                w.close()

    async def start(self, host: str, port: int) -> asyncio.Server:
        """Listen on ``host:port`` and start the phase schedules (their clock starts now)."""
        self._loop = asyncio.get_running_loop()
        for name, wire in (("up", self.up), ("down", self.down)):
            if wire is not None and name in self.phases:
                self._drivers.append(asyncio.create_task(self._drive(name, wire, self.phases[name])))
        if self.up is None:
            return await asyncio.start_server(self._serve, host, port, reuse_address=True)
        sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        _window(sock, self.hidden_queue)  # accepted sockets inherit it, window and segment size included
        sock.bind((host, port))
        return await asyncio.start_server(self._serve, sock=sock,
                                          limit=HIDDEN_READ_AHEAD if self.hidden_queue else READ_AHEAD)

    def close(self) -> None:
        """Stop the phase schedules (the server returned by :meth:`start` is closed by its owner)."""
        for task in self._drivers:
            task.cancel()
        self._drivers.clear()


def _address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "127.0.0.1", int(port)


def parse_phases(text: str) -> Phases:
    """``"10:1024,10:128,4:0"`` (seconds:kbit/s per phase) → ``((10.0, 128000.0), (10.0, 16000.0), (4.0, 0.0))``
    in seconds and bytes/s."""
    phases: list[tuple[float, float]] = []
    for part in text.split(","):
        seconds, sep, rate = part.strip().partition(":")
        try:
            if not sep:
                raise ValueError
            phases.append((float(seconds), kbit(float(rate))))
        except ValueError:
            raise ValueError(f"expected SECONDS:KBIT[,SECONDS:KBIT...], got {text!r}") from None
    result = tuple(phases)
    _check_phases(result)
    return result


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m roslink_mqtt.shaped_link", description=__doc__.split("\n\n")[0])
    p.add_argument("--listen", type=_address, required=True, help="HOST:PORT to accept connections on")
    p.add_argument("--to", type=_address, required=True, help="HOST:PORT to forward them to (the broker)")
    p.add_argument("--delay-ms", type=float, default=20.0, help="mean one-way delay (default: %(default)s)")
    p.add_argument("--jitter-ms", type=float, default=5.0, help="its standard deviation (default: %(default)s)")
    p.add_argument("--loss", type=float, default=0.0, help="share of chunks lost and resent (default: 0)")
    p.add_argument("--rto-ms", type=float, default=200.0, help="what a loss costs (default: %(default)s)")
    p.add_argument("--up-kbit", type=float, default=0.0,
                   help="bandwidth from clients to the target in kbit/s, shared by all connections (default: 0, "
                        "unlimited)")
    p.add_argument("--down-kbit", type=float, default=0.0, help="bandwidth back to the clients (default: 0, unlimited)")
    p.add_argument("--phases", default=None, metavar="S:KBIT,...",
                   help="uplink capacity that changes, instead of --up-kbit: seconds:kbit/s per phase, e.g. "
                        "'10:1024,10:128,4:0,10:256' (0: a dead spot, connections stay open); from when the proxy "
                        "listens, repeated")
    p.add_argument("--down-phases", default=None, metavar="S:KBIT,...", help="the same for the downlink")
    p.add_argument("--phases-once", action="store_true",
                   help="play the phases once, then keep the last phase's rate (default: repeat them)")
    p.add_argument("--hidden-queue", action="store_true",
                   help="the link's queue hides from the senders (a split-TCP proxy, VPN concentrator or load "
                        "balancer that acknowledges at once): one FIFO per direction for every connection; "
                        "default: the queue waits in the senders' sockets (a modem)")
    p.add_argument("--queue-kb", type=float, default=None,
                   help=f"bound of each hidden FIFO in kB, beyond which the hop stops reading (default: "
                        f"{HIDDEN_QUEUE_SECONDS:g} s of the direction's highest rate, at least "
                        f"{HIDDEN_QUEUE_MIN // 1024} KiB)")
    p.add_argument("--seed", type=int, default=None, help="random seed, for repeatable runs")
    args = p.parse_args(argv)
    try:
        args.shape = Shape(args.delay_ms / 1000, args.jitter_ms / 1000, args.loss, args.rto_ms / 1000)
    except ValueError as e:
        p.error(str(e))
    if args.up_kbit < 0 or args.down_kbit < 0:
        p.error("--up-kbit and --down-kbit must not be negative (0: unlimited)")
    for flag, attr, fixed in (("--phases", "phases", "up_kbit"), ("--down-phases", "down_phases", "down_kbit")):
        text = getattr(args, attr)
        if text is None:
            continue
        if getattr(args, fixed):
            p.error(f"{flag} replaces --{fixed.replace('_', '-')}: give one of them")
        try:
            setattr(args, attr, parse_phases(text))
        except ValueError as e:
            p.error(f"{flag}: {e}")
    if args.hidden_queue and not (args.up_kbit or args.down_kbit or args.phases or args.down_phases):
        p.error("--hidden-queue needs a bottleneck: --up-kbit, --down-kbit or phases")
    if args.queue_kb is not None and (not args.hidden_queue or args.queue_kb <= 0):
        p.error("--queue-kb is a positive bound of the --hidden-queue FIFO")
    return args


def kbit(rate: float) -> float:
    """kbit/s → bytes/s (1 kbit = 1,000 bits, as links are sold)."""
    return rate * 1000 / 8


def _rate_text(rate: float) -> str:
    return f"{rate * 8 / 1000:g} kbit/s" if rate else "unlimited"


def _phases_text(phases: Phases) -> str:
    return ",".join(f"{seconds:g}:{rate * 8 / 1000:g}" for seconds, rate in phases)


async def _run(args: argparse.Namespace) -> None:
    began = time.monotonic()

    def on_rate(direction: str, rate: float) -> None:
        print(f"shaped link: {time.monotonic() - began:.1f} s: {direction} {rate * 8 / 1000:g} kbit/s", flush=True)

    link = ShapedLink(args.to, args.shape, seed=args.seed, up_rate=kbit(args.up_kbit),
                      down_rate=kbit(args.down_kbit), hidden_queue=args.hidden_queue,
                      queue_bytes=None if args.queue_kb is None else int(args.queue_kb * 1000),
                      up_phases=args.phases, down_phases=args.down_phases, repeat_phases=not args.phases_once,
                      on_rate=on_rate if args.phases or args.down_phases else None)
    server = await link.start(*args.listen)
    shape = args.shape
    up = f"phases {_phases_text(args.phases)}" if args.phases else _rate_text(kbit(args.up_kbit))
    down = f"phases {_phases_text(args.down_phases)}" if args.down_phases else _rate_text(kbit(args.down_kbit))
    if args.phases or args.down_phases:
        up += " (once)" if args.phases_once and args.phases else ""
        down += " (once)" if args.phases_once and args.down_phases else ""
    queue = "visible queue (in the senders' sockets)"
    if args.hidden_queue:
        bounds = [f"{name} {wire.limit / 1000:g} kB" for name, wire in (("up", link.up), ("down", link.down))
                  if wire is not None and wire.limit is not None]
        queue = f"hidden queue (one FIFO per direction, bound {', '.join(bounds)})"
    print(f"shaped link {args.listen[0]}:{args.listen[1]} -> {args.to[0]}:{args.to[1]}: "
          f"{shape.delay * 1000:g} ± {shape.jitter * 1000:g} ms each way, loss {shape.loss:g} "
          f"(+{shape.rto * 1000:g} ms), up {up}, down {down}, {queue}", flush=True)
    try:
        async with server:
            await server.serve_forever()
    finally:
        link.close()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    started = time.monotonic()
    try:
        asyncio.run(_run(args))
    except KeyboardInterrupt:
        pass
    except OSError as e:
        print(f"shaped link: {e}", file=sys.stderr)
        return 1
    print(f"shaped link: stopped after {time.monotonic() - started:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
