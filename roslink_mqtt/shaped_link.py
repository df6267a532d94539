"""A TCP proxy that makes a loopback connection behave like a long, uneven, thin Internet link.

    python -m roslink_mqtt.shaped_link --listen 127.0.0.1:18830 --to 127.0.0.1:1883 \
        --delay-ms 60 --jitter-ms 20 --loss 0.01 --up-kbit 256 --down-kbit 1024

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
client): one link per direction, shared by every connection through the proxy, like a cellular modem. It carries
one packet at a time, in the order the packets arrived from any connection (a FIFO), each taking
``size / rate`` of link time; the delay starts when a packet has left. A connection's next packet is read only
once its previous one is on the link, so what the link cannot carry yet waits in the *sender's* socket, where
the sender sees it (``SIOCOUTQ``) as it would see a real modem's queue (unacknowledged bytes); the proxy's own
receive buffers are kept small (``RCVBUF``) so that little waits unseen.

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
from dataclasses import dataclass

CHUNK = 65536
QUEUED_CHUNKS = 1024  # per direction: a reader this far ahead of the writer waits (bounded memory)
MTU_PAYLOAD = 1448  # bytes of one full TCP segment on an Ethernet-sized path: the unit a thin link carries
RCVBUF = 1024  # SO_RCVBUF of the proxy's sockets on a rate-limited link (the kernel doubles it, to ~2 KiB)
READ_AHEAD = 512  # asyncio's reader pauses its socket beyond twice this: little read ahead of the wire, unseen


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

    def release_time(self, now: float) -> float:
        """The moment a chunk read at ``now`` may be written."""
        shape = self.shape
        delay = max(0.0, self.rng.gauss(shape.delay, shape.jitter)) if shape.jitter else shape.delay
        if shape.loss and self.rng.random() < shape.loss:
            delay += shape.rto  # the segment was lost and sent again after the retransmission timeout
        self.last = max(self.last, now + delay)
        return self.last


class Wire:
    """One direction of a rate-limited link, shared by every connection: a FIFO of packets, one at a time.

    ``reserve`` books link time for ``size`` bytes after everything booked before (virtual time, so no lock is
    needed in one event loop) and returns the moment the last byte has left.
    """

    def __init__(self, rate: float) -> None:
        if rate <= 0:
            raise ValueError("a link's rate is a positive number of bytes per second")
        self.rate = rate
        self.free_at = 0.0  # when the link has sent everything booked so far
        self.carried = 0  # bytes, for tests and the final report

    @property
    def packet_size(self) -> int:
        """Bytes read and booked at once: a TCP segment on thin links, more on fast ones (≈1 ms of link time)."""
        return max(MTU_PAYLOAD, min(CHUNK, int(self.rate / 1000)))

    def reserve(self, size: int, now: float) -> float:
        start = max(now, self.free_at)
        self.free_at = start + size / self.rate
        self.carried += size
        return self.free_at


def _nodelay(writer: asyncio.StreamWriter) -> None:
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, schedule: Schedule,
                wire: Wire | None = None) -> None:
    """Copy one direction through the wire (if rate-limited) and the schedule; end (and half-close) with the reader."""
    queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue(QUEUED_CHUNKS)
    loop = asyncio.get_running_loop()

    async def read() -> None:
        try:
            while chunk := await reader.read(wire.packet_size if wire is not None else CHUNK):
                sent = loop.time()
                if wire is not None:
                    sent = wire.reserve(len(chunk), sent)
                    # the next packet of this connection stays in its sender's socket until this one has left
                    await asyncio.sleep(max(0.0, sent - loop.time()))
                await queue.put((schedule.release_time(sent), chunk))
        except (ConnectionError, OSError):
            pass
        await queue.put(None)

    async def write() -> None:
        while (item := await queue.get()) is not None:
            release, chunk = item
            if (wait := release - loop.time()) > 0:
                await asyncio.sleep(wait)
            writer.write(chunk)
            await writer.drain()
        with contextlib.suppress(OSError):
            writer.write_eof()

    reading = asyncio.create_task(read())
    try:
        await write()
    except (ConnectionError, OSError):
        pass
    finally:
        reading.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reading


def _small_rcvbuf(sock: socket.socket) -> None:
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)


class ShapedLink:
    """The proxy: one listening socket, every accepted connection forwarded to ``target`` through two schedules.

    ``up_rate`` / ``down_rate``: bytes per second from clients to the target and back (0: unlimited), each one
    :class:`Wire` shared by every connection.
    """

    def __init__(self, target: tuple[str, int], shape: Shape, *, seed: int | None = None, up_rate: float = 0.0,
                 down_rate: float = 0.0) -> None:
        self.target, self.shape = target, shape
        self.rng = random.Random(seed)
        self.connections = 0
        self.up = Wire(up_rate) if up_rate else None
        self.down = Wire(down_rate) if down_rate else None

    async def _connect_upstream(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        if self.down is None:
            return await asyncio.open_connection(*self.target)
        sock = socket.socket(socket.AF_INET6 if ":" in self.target[0] else socket.AF_INET, socket.SOCK_STREAM)
        try:
            _small_rcvbuf(sock)  # before connecting: the window the target may fill is set at the handshake
            sock.setblocking(False)
            await asyncio.get_running_loop().sock_connect(sock, self.target)
        except OSError:
            sock.close()
            raise
        return await asyncio.open_connection(sock=sock, limit=READ_AHEAD)

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
                _pump(client_reader, upstream_writer, Schedule(self.shape, self.rng), self.up),
                _pump(upstream_reader, client_writer, Schedule(self.shape, self.rng), self.down),
            )
        finally:
            for w in (client_writer, upstream_writer):
                w.close()

    async def start(self, host: str, port: int) -> asyncio.Server:
        if self.up is None:
            return await asyncio.start_server(self._serve, host, port, reuse_address=True)
        sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        _small_rcvbuf(sock)  # accepted sockets inherit it, window included
        sock.bind((host, port))
        return await asyncio.start_server(self._serve, sock=sock, limit=READ_AHEAD)


def _address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "127.0.0.1", int(port)


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
    p.add_argument("--seed", type=int, default=None, help="random seed, for repeatable runs")
    args = p.parse_args(argv)
    try:
        args.shape = Shape(args.delay_ms / 1000, args.jitter_ms / 1000, args.loss, args.rto_ms / 1000)
    except ValueError as e:
        p.error(str(e))
    if args.up_kbit < 0 or args.down_kbit < 0:
        p.error("--up-kbit and --down-kbit must not be negative (0: unlimited)")
    return args


def kbit(rate: float) -> float:
    """kbit/s → bytes/s (1 kbit = 1,000 bits, as links are sold)."""
    return rate * 1000 / 8


def _rate_text(rate: float) -> str:
    return f"{rate * 8 / 1000:g} kbit/s" if rate else "unlimited"


async def _run(args: argparse.Namespace) -> None:
    link = ShapedLink(args.to, args.shape, seed=args.seed, up_rate=kbit(args.up_kbit),
                      down_rate=kbit(args.down_kbit))
    server = await link.start(*args.listen)
    shape = args.shape
    print(f"shaped link {args.listen[0]}:{args.listen[1]} -> {args.to[0]}:{args.to[1]}: "
          f"{shape.delay * 1000:g} ± {shape.jitter * 1000:g} ms each way, loss {shape.loss:g} "
          f"(+{shape.rto * 1000:g} ms), up {_rate_text(kbit(args.up_kbit))}, down {_rate_text(kbit(args.down_kbit))}",
          flush=True)
    async with server:
        await server.serve_forever()


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
